"""``morphspace serve --workers N``: N server processes on one port, kept running (Linux).

The supervisor is the process ``morphspace serve`` started. It stays small (it never imports the
app, numpy or the engine, and starts no thread), and:

1. binds the address with ``SO_REUSEPORT`` and keeps that socket without listening on it: it
   holds the port (and tells which one when port 0 was asked for);
2. creates the counter board (shared memory, server/workers/board.py) and the jobs' wake-up pipe;
3. forks the N workers. Each opens its own listening socket on the same address with
   ``SO_REUSEPORT`` and serves it with uvicorn; the kernel spreads new connections over the
   listening sockets by a hash of each connection's addresses, so a connection stays with the
   worker that accepted it. Worker 0 runs the job queue (server/workers/context.py);
4. waits. A worker that ends, for whatever reason, is reaped, its counters are retired into the
   board's totals and its index is started again: at once if it had run for ``QUICK`` seconds,
   else after 0.5 s, doubling up to 8 s. After ``GIVE_UP`` quick ends of one index in a row the
   supervisor stops the others and exits with status 1, naming the worker and how it ended.
   SIGTERM, SIGINT or SIGHUP stop every worker (SIGTERM, then SIGKILL after ``grace`` s) and
   end the supervisor with status 0.

A worker dies with the supervisor (``PR_SET_PDEATHSIG``), so none outlives it, and a job worker
dies with its server worker (server/jobs/worker.py watches its stdin).
"""

from __future__ import annotations

import ctypes
import os
import signal
import socket
import sys
import time
import traceback

from server.workers.board import CounterBoard
from server.workers.context import WorkerContext

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
QUICK = 10.0      # seconds: a worker that ends sooner after its start counts as failing to start
GIVE_UP = 5       # quick ends in a row of one index before the supervisor gives up
BACKLOG = 2048
_PR_SET_PDEATHSIG = 1


def resolve(host, port):
    """(family, address) to bind for ``host`` and ``port``."""
    family, _, _, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                                  flags=socket.AI_PASSIVE)[0]
    return family, address


def check_free(family, address, host):
    """Raise OSError when a socket is already bound to ``address`` (port 0 is always free).

    Workers join the port with ``SO_REUSEPORT``, which another server's workers would share
    without a word: a probe bound without it fails on any socket bound there (a TIME_WAIT
    connection is allowed, ``SO_REUSEADDR``), so a second server on the port is refused."""
    if address[1] == 0:
        return
    probe = socket.socket(family, socket.SOCK_STREAM)
    try:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        probe.bind(address)
    except OSError as exc:
        raise OSError(f"{host}:{address[1]} is already in use (another server on this port? {exc.strerror})") from None
    finally:
        probe.close()


def reuseport_socket(family, address, listen=True):
    """A TCP socket bound to ``address`` with SO_REUSEADDR and SO_REUSEPORT (listening if asked)."""
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        sock.bind(address)
        if listen:
            sock.listen(BACKLOG)
            sock.setblocking(False)
    except OSError:
        sock.close()
        raise
    return sock


def describe_status(status):
    """'exited with status 1', 'was killed by SIGKILL' for a waitpid status."""
    if os.WIFSIGNALED(status):
        number = os.WTERMSIG(status)
        try:
            return f"was killed by {signal.Signals(number).name}"
        except ValueError:
            return f"was killed by signal {number}"
    return f"exited with status {os.waitstatus_to_exitcode(status)}"


def _die_with_parent(parent):
    """SIGTERM this process when ``parent`` ends (Linux prctl); exit now if it already has."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    if os.getppid() != parent:
        os._exit(0)


class Supervisor:
    """Forks ``workers`` processes that each run ``serve(context, sock)`` and keeps them running.

    ``serve`` is called in the forked worker with its WorkerContext and its listening socket and
    returns an exit status; ``log`` prints a line (default: stderr).
    """

    def __init__(self, workers, serve, host, port, *, grace=10.0, log=None):
        if workers < 1:
            raise ValueError(f"--workers must be at least 1, got {workers}")
        self.workers, self.serve, self.grace = int(workers), serve, float(grace)
        self.family, self.address = resolve(host, port)
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        check_free(self.family, self.address, host)
        self.reserve = reuseport_socket(self.family, self.address, listen=False)
        self.address = self.reserve.getsockname()
        self.port = self.address[1]
        self.board = CounterBoard(self.workers)
        self.wake_read, self.wake_write = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self.pids = {}             # pid -> index
        self.started = {}          # index -> monotonic start
        self.quick = [0] * self.workers
        self.due = {}              # index -> monotonic time to start it again
        self.failure = None
        self._mask = None

    # --- the supervisor's loop ------------------------------------------------------------------
    def run(self):
        """Start the workers and keep them running until a stop signal; returns the exit status."""
        waited = {signal.SIGCHLD, *STOP_SIGNALS}
        self._mask = signal.pthread_sigmask(signal.SIG_BLOCK, waited)
        try:
            for index in range(self.workers):
                self._start(index)
            while self.failure is None:
                timeout = 1.0
                if self.due:
                    timeout = max(0.0, min(timeout, min(self.due.values()) - time.monotonic()))
                info = signal.sigtimedwait(waited, timeout)
                if info is not None and info.si_signo in STOP_SIGNALS:
                    self.log(f"morphspace: {signal.Signals(info.si_signo).name}: stopping {len(self.pids)} workers")
                    break
                self._reap()
                now = time.monotonic()
                for index in [i for i, due in self.due.items() if due <= now]:
                    del self.due[index]
                    self._start(index)
            self._stop_all()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._mask)
            self.reserve.close()
        if self.failure:
            self.log(f"morphspace: giving up: {self.failure}")
            return 1
        return 0

    def _start(self, index):
        sys.stdout.flush()
        sys.stderr.flush()
        parent = os.getpid()
        pid = os.fork()
        if pid == 0:
            self._worker(index, parent)  # never returns
        self.pids[pid] = index
        self.started[index] = time.monotonic()
        self.board.set_slot(index, pid=pid, started_at=time.time())

    def _worker(self, index, parent):
        status = 1
        try:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._mask)
            _die_with_parent(parent)
            self.reserve.close()
            context = WorkerContext(index, self.workers, self.board, self.wake_read, self.wake_write)
            sock = reuseport_socket(self.family, self.address)
            status = self.serve(context, sock)
        except SystemExit as exc:
            status = exc.code if isinstance(exc.code, int) else 1
        except BaseException:  # noqa: BLE001 - reported, then this process ends
            traceback.print_exc()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(status or 0)

    def _reap(self):
        """Collect ended workers: retire their counters, plan their restart."""
        while True:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                return
            if pid == 0:
                return
            index = self.pids.pop(pid, None)
            if index is None:
                continue
            lived = time.monotonic() - self.started[index]
            how = describe_status(status)
            self.board.retire(index)
            self.quick[index] = self.quick[index] + 1 if lived < QUICK else 0
            slot = self.board.slot(index)
            self.board.set_slot(index, pid=None, restarts=slot.get("restarts", 0) + 1,
                                last_exit=f"pid {pid} {how} after {lived:.1f} s at {time.strftime('%H:%M:%S')}")
            if self.quick[index] >= GIVE_UP:
                self.failure = (f"worker {index} ended {GIVE_UP} times in a row within {QUICK:.0f} s of starting "
                                f"(last: pid {pid} {how})")
                return
            delay = 0.0 if self.quick[index] == 0 else min(0.5 * 2 ** (self.quick[index] - 1), 8.0)
            self.log(f"morphspace: worker {index} (pid {pid}) {how} after {lived:.1f} s; starting it again"
                     + (f" in {delay:.1f} s" if delay else ""))
            self.due[index] = time.monotonic() + delay

    def _stop_all(self):
        for pid in self.pids:
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + self.grace
        while self.pids and time.monotonic() < deadline:
            signal.sigtimedwait({signal.SIGCHLD}, 0.1)
            self._collect()
        for pid in self.pids:
            self.log(f"morphspace: worker {self.pids[pid]} (pid {pid}) did not stop in {self.grace:.0f} s; killing it")
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        while self.pids:
            try:
                pid, _ = os.waitpid(-1, 0)
            except ChildProcessError:
                break
            self.pids.pop(pid, None)

    def _collect(self):
        while self.pids:
            try:
                pid, _ = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                self.pids.clear()
                return
            if pid == 0:
                return
            self.pids.pop(pid, None)

"""The ``morphspace`` command line.

Subcommands register themselves in ``COMMANDS``; each has an ``add_arguments(parser)`` and a
``run(args) -> int``. Errors in user input end with a one-line message and exit status 2; Ctrl-C
ends a command with status 130 and SIGTERM with 143 (``serve`` stops gracefully on either), each
after the command's own clean-up (temporary files removed, nothing half-written left).
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import signal
import sys
import threading
from pathlib import Path

from server.commands import bench, blend, build, eval_params, play, synth
from server.commands import eval as eval_command
from server.commands import align, build_graph, eval_align, eval_graph, export, serve

COMMANDS = {
    "synth": synth,
    "build": build,
    "build-graph": build_graph,
    "blend": blend,
    "eval": eval_command,
    "bench": bench,
    "play": play,
    "eval-params": eval_params,
    "align": align,
    "eval-align": eval_align,
    "eval-graph": eval_graph,
    "serve": serve,
    "export": export,
}


def build_parser():
    parser = argparse.ArgumentParser(
        prog="morphspace",
        description="Parametric real-time animation of performance-captured mesh sequences.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parser.commands = {}  # name -> the command's own parser (its usage goes with its errors)
    for name, module in COMMANDS.items():
        doc = (module.__doc__ or "").strip().splitlines()
        p = sub.add_parser(name, help=doc[0] if doc else None, description=(module.__doc__ or "").strip(),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        parser.commands[name] = p
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that clean-ups (``finally``, atomic writes) run."""


def _on_sigterm(main_pid):
    def handler(signum, frame):
        if os.getpid() != main_pid:  # a forked worker: die as SIGTERM would have it
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        if _starting_a_process(frame):  # not now: once the worker is registered, it is ended with the rest
            threading.Timer(0.02, os.kill, (main_pid, signal.SIGTERM)).start()
            return
        for child in multiprocessing.active_children():  # the worker processes end now, not when their task
            child.terminate()                            # is done (a pool's shutdown waits for running tasks)
        for pid in _grandchildren(main_pid):  # a forkserver's workers that no pool had registered yet
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGTERM)
        raise Terminated()
    return handler


def _starting_a_process(frame):
    """Whether the main thread is inside ``multiprocessing``'s ``BaseProcess.start``.

    Raised there, the signal's exception left a worker half started: forked by the forkserver but
    never registered as a child process (so in no ``active_children()``), it outlived the command
    and printed a ``FileNotFoundError`` or ``EOFError`` traceback after "terminated" (it unpickled
    its start-up data after the pool's semaphores were unlinked, or found its pipe closed), or the
    forkserver itself died on the half-sent request with an ``EOFError`` traceback (4 runs of 6
    signalled at "try roots"). The handler sends the signal again 20 ms later instead."""
    while frame is not None:
        code = frame.f_code
        if code.co_name == "start" and code.co_filename.endswith(os.path.join("multiprocessing", "process.py")):
            return True
        frame = frame.f_back
    return False


def _grandchildren(pid):
    """The pids of the children of ``pid``'s children (Linux ``/proc``; none elsewhere): a
    forkserver pool's workers are the forkserver's children."""
    def children(of):
        found = set()
        for task in Path(f"/proc/{of}/task").glob("*"):
            with contextlib.suppress(OSError, ValueError):
                found |= {int(c) for c in (task / "children").read_text().split()}
        return found

    return {g for child in children(pid) for g in children(child)}


def main(argv=None):
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # the command's usage, not the top level's (exit status 2)
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
    previous = None
    if os.name == "posix" and threading.current_thread() is threading.main_thread():
        # (only the main thread may set a handler; `serve`'s uvicorn takes the signal while it serves,
        # then restores this handler and raises the signal again once it has stopped gracefully)
        previous = signal.signal(signal.SIGTERM, _on_sigterm(os.getpid()))
    try:
        return COMMANDS[args.command].run(args)
    except BrokenPipeError:
        # the reader went away (`morphspace play ... | head`): nothing more to say to it, no error;
        # stdout is pointed at /dev/null so that the flush at exit does not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except (ValueError, OSError) as exc:
        print(f"morphspace {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        print(f"morphspace {args.command}: {'terminated' if terminated else 'interrupted'}", file=sys.stderr)
        return 143 if terminated else 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())

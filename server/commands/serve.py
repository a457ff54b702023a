"""Serve motion spaces: REST, the WebSocket stream and the browser client.

Settings come from the environment (MORPHSPACE_DATA_DIR, MORPHSPACE_TOKEN, MORPHSPACE_CORS_ORIGINS,
MORPHSPACE_DASK_SCHEDULER, ... see docs/rest.md); the options below override them. The server
refuses to bind a non-loopback address without a token unless --allow-open-bind is given.

--workers N (Linux) serves from N processes on the same port: the kernel spreads connections over
them (SO_REUSEPORT), worker 0 runs the job queue, /v1/health adds up every worker's counters, and
a worker that ends is started again (server/workers/supervisor.py).
"""

from __future__ import annotations

from pathlib import Path


def add_arguments(parser):
    parser.add_argument("--data-dir", type=Path, help="data directory (spaces/, datasets/, jobs.sqlite)")
    parser.add_argument("--host", help="address to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="port (default 8000)")
    parser.add_argument("--workers", type=int,
                        help="server processes sharing the port (default 1; MORPHSPACE_WORKERS)")
    parser.add_argument("--dask-scheduler", help="run jobs on this Dask scheduler (tcp://host:8786)")
    parser.add_argument("--stall-timeout", type=float, metavar="SECONDS",
                        help="close a stream connection that takes no frame for this long, with code 1008 "
                             "(default 60; MORPHSPACE_STREAM_STALL_TIMEOUT)")
    parser.add_argument("--allow-open-bind", action="store_true",
                        help="serve a non-loopback address without a token")
    parser.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])


def run(args):
    from server.settings import Settings, check_bind

    overrides = {k: v for k, v in {"data_dir": args.data_dir, "host": args.host, "port": args.port,
                                   "dask_scheduler": args.dask_scheduler, "workers": args.workers,
                                   "stream_stall_timeout": args.stall_timeout}.items() if v is not None}
    if args.allow_open_bind:
        overrides["allow_open_bind"] = True
    settings = read_settings(Settings, overrides)
    check_bind(settings, settings.host)
    if settings.workers > 1:
        return _run_workers(overrides, args.log_level)
    import uvicorn

    from server.app import create_app
    from server.workers.supervisor import check_free, resolve

    family, address = resolve(settings.host, settings.port)
    check_free(family, address, settings.host)  # before the start-up work, as with --workers
    app = create_app(settings)
    print(f"morphspace: serving {settings.spaces_dir} on http://{settings.host}:{settings.port}/ "
          f"(browser client at /, API docs at /docs)", flush=True)
    server = uvicorn.Server(uvicorn.Config(app, **uvicorn_options(settings, args.log_level), host=settings.host,
                                          port=settings.port))
    keep_an_ignored_ctrl_c(server)
    # uvicorn takes Ctrl-C and SIGTERM while it serves, stops gracefully, then restores the
    # handlers it found and raises the signal again: Ctrl-C's KeyboardInterrupt, and the CLI's
    # SIGTERM handler (server.cli), end `serve` as they end every command (130 or 143, a line
    # saying which). uvicorn.run() swallowed the KeyboardInterrupt: Ctrl-C ended with status 0.
    server.run()
    return 0


def keep_an_ignored_ctrl_c(server):
    """A Ctrl-C ignored when ``serve`` started stays ignored, as every other command ignores it
    (Python keeps an inherited SIG_IGN; a shell starts background jobs so). uvicorn took it anyway,
    stopped, then raised it again into the restored SIG_IGN: the server ended with status 0 and no
    word (seen when the test suite ran in the background)."""
    import signal

    if signal.getsignal(signal.SIGINT) != signal.SIG_IGN:
        return
    handle_exit = server.handle_exit  # installed by uvicorn for SIGINT and SIGTERM while it serves
    server.handle_exit = lambda signum, frame: None if signum == signal.SIGINT else handle_exit(signum, frame)


OPTIONS = {"data_dir": "--data-dir", "host": "--host", "port": "--port", "dask_scheduler": "--dask-scheduler",
           "workers": "--workers", "stream_stall_timeout": "--stall-timeout"}


def read_settings(settings_class, overrides):
    """The settings from the environment and ``overrides`` (the options given). A bad value is a
    ValueError on one line naming the option or the environment variable it came from
    (``--port 99999: Input should be less than or equal to 65535``, ``MORPHSPACE_PORT=abc: ...``),
    not pydantic's report in the settings' own field names."""
    from pydantic import ValidationError

    try:
        return settings_class(**overrides)
    except ValidationError as exc:
        problems = []
        for error in exc.errors():
            field = str(error["loc"][0]) if error["loc"] else ""
            given = error.get("input")
            source = (f"{OPTIONS[field]} {given}" if field in overrides and field in OPTIONS
                      else f"MORPHSPACE_{field.upper()}={given}")
            problems.append(f"{source}: {error['msg']}")
        raise ValueError("; ".join(problems)) from None


def uvicorn_options(settings, log_level):
    from server.protocol import websocket_max_size
    from server.stream import CLOSE_GRACE
    from server.transport import StreamProtocol  # uvicorn's sans-I/O WebSocket protocol, bounded

    # keepalive pings must not close a stalled stream before its own timeout does (a client that
    # reads nothing cannot answer them)
    return {"ws": StreamProtocol, "ws_max_size": websocket_max_size(settings.stream_max_message),
            "ws_ping_timeout": max(20.0, settings.stream_stall_timeout + CLOSE_GRACE),
            "log_level": log_level, "timeout_graceful_shutdown": 5}


def _run_workers(overrides, log_level):
    """Serve from several processes: replace this process by the supervisor in a fresh
    interpreter (``python -m server.workers``), which forks the workers without numpy, the
    engine or their threads in it. The settings travel in the environment."""
    import os
    import sys

    if not sys.platform.startswith("linux"):
        raise ValueError("--workers above 1 needs Linux (SO_REUSEPORT and PR_SET_PDEATHSIG)")
    for key, value in overrides.items():
        os.environ[f"MORPHSPACE_{key.upper()}"] = str(value)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, [sys.executable, "-m", "server.workers", "--log-level", log_level])

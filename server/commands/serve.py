"""Serve motion spaces: REST, the WebSocket stream and the browser client.

Settings come from the environment (MORPHSPACE_DATA_DIR, MORPHSPACE_TOKEN, MORPHSPACE_CORS_ORIGINS,
MORPHSPACE_DASK_SCHEDULER, ... see docs/rest.md); the options below override them. The server
refuses to bind a non-loopback address without a token unless --allow-open-bind is given.
"""

from __future__ import annotations

from pathlib import Path


def add_arguments(parser):
    parser.add_argument("--data-dir", type=Path, help="data directory (spaces/, datasets/, jobs.sqlite)")
    parser.add_argument("--host", help="address to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="port (default 8000)")
    parser.add_argument("--dask-scheduler", help="run jobs on this Dask scheduler (tcp://host:8786)")
    parser.add_argument("--allow-open-bind", action="store_true",
                        help="serve a non-loopback address without a token")
    parser.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])


def run(args):
    import uvicorn

    from server.app import create_app
    from server.settings import Settings, check_bind

    overrides = {k: v for k, v in {"data_dir": args.data_dir, "host": args.host, "port": args.port,
                                   "dask_scheduler": args.dask_scheduler}.items() if v is not None}
    if args.allow_open_bind:
        overrides["allow_open_bind"] = True
    settings = Settings(**overrides)
    check_bind(settings, settings.host)
    app = create_app(settings)
    print(f"morphspace: serving {settings.spaces_dir} on http://{settings.host}:{settings.port}/ "
          f"(browser client at /, API docs at /docs)", flush=True)
    uvicorn.run(app, host=settings.host, port=settings.port, ws="websockets-sansio",
                ws_max_size=max(1 << 20, settings.stream_max_message * 4), log_level=args.log_level,
                timeout_graceful_shutdown=5)
    return 0

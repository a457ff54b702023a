"""``python -m server.workers --log-level info``: the supervisor of ``morphspace serve --workers N``.

``morphspace serve`` replaces itself with this module in a fresh interpreter (same pid), so the
process that forks the workers holds no numpy, engine or thread. The settings come from the
environment (``MORPHSPACE_*``), where the command put its options.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial

from server.commands.serve import uvicorn_options
from server.settings import Settings, check_bind
from server.workers.supervisor import Supervisor


def serve_worker(settings, log_level, context, sock):
    """One worker (in the forked process): the app on ``sock`` until it is told to stop. Its
    BLAS and OpenMP pools get one thread: N workers share the cores already (the job processes
    it starts are not limited)."""
    import uvicorn
    from threadpoolctl import threadpool_limits

    from server.app import create_app

    threadpool_limits(1)

    config = uvicorn.Config(create_app(settings, worker=context), **uvicorn_options(settings, log_level))
    uvicorn.Server(config).run(sockets=[sock])
    return 0


def main(argv=None):
    parser = argparse.ArgumentParser(prog="morphspace serve", description=__doc__)
    parser.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    args = parser.parse_args(argv)
    try:
        settings = Settings()
        check_bind(settings, settings.host)
        supervisor = Supervisor(settings.workers, partial(serve_worker, settings, args.log_level),
                                settings.host, settings.port)
    except (ValueError, OSError) as exc:
        print(f"morphspace serve: error: {exc}", file=sys.stderr)
        return 2
    print(f"morphspace: serving {settings.spaces_dir} on http://{settings.host}:{supervisor.port}/ from "
          f"{settings.workers} worker processes (browser client at /, API docs at /docs)", flush=True)
    return supervisor.run()


if __name__ == "__main__":
    sys.exit(main())

"""The FastAPI application: ``create_app(settings)``.

REST under ``/v1`` (motion spaces, datasets, jobs), the WebSocket stream at ``/v1/stream``, the
browser client at ``/``. Nothing happens at import time; ``morphspace serve`` (or uvicorn's
``--factory server.app:create_app``) builds the app.
"""

from __future__ import annotations

import gc
import logging
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, WebSocket
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import RedirectResponse
from fastapi.staticfiles import StaticFiles

from server import __version__
from server.api import datasets, jobs, spaces
from server.jobs import JobService
from server.registry import SpaceRegistry
from server.scheduler import FrameScheduler
from server.settings import Settings
from server.stream import StreamSession, StreamStats

log = logging.getLogger("morphspace.server")
WEB_CLIENT = Path(__file__).resolve().parent.parent / "web_client" / "static"


def create_app(settings: Settings | None = None) -> FastAPI:
    """The morphspace server for ``settings`` (default: from the environment)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app):
        for directory in (settings.data_dir, settings.spaces_dir, settings.datasets_dir, settings.work_dir):
            directory.mkdir(parents=True, exist_ok=True)
        await app.state.jobs.start()
        # Everything loaded so far lives as long as the server: keep it out of the cyclic
        # collector's full passes, which otherwise stall the event loop (and every stream) for
        # ~100 ms now and then (the registry does the same after opening a space).
        gc.freeze()
        try:
            yield
        finally:
            await app.state.jobs.stop()
            app.state.registry.close()

    app = FastAPI(title="morphspace", version=__version__, lifespan=lifespan,
                  description="Motion spaces from 4D performance capture: REST for spaces, datasets and jobs; "
                              "a WebSocket stream of blended frames at /v1/stream (see docs/protocol.md).")
    app.state.settings = settings
    app.state.registry = SpaceRegistry(settings.spaces_dir)
    app.state.stream_stats = StreamStats()
    app.state.frame_scheduler = FrameScheduler()
    app.state.jobs = JobService(settings, app.state.registry)
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["*"],
                           allow_headers=["Authorization", "Content-Type"])

    app.include_router(spaces.router, prefix="/v1")
    app.include_router(datasets.router, prefix="/v1")
    app.include_router(jobs.router, prefix="/v1")

    @app.get("/v1/health", tags=["server"], summary="Liveness and counters")
    def health():
        stats, scheduler = app.state.stream_stats, app.state.frame_scheduler
        return {"status": "ok", "version": __version__, "spaces": len(app.state.registry.names()),
                "connections": stats.connections, "frames_sent": stats.frames, "frames_dropped": stats.dropped,
                "stream_errors": stats.errors, "scheduler": scheduler.counters()}

    @app.websocket("/v1/stream")
    async def stream(websocket: WebSocket):
        await StreamSession(websocket, app.state.registry, settings, app.state.stream_stats,
                            app.state.frame_scheduler).run()

    if WEB_CLIENT.is_dir():
        app.mount("/app", StaticFiles(directory=WEB_CLIENT, html=True), name="web_client")

        @app.get("/", include_in_schema=False)
        def index():
            return RedirectResponse("/app/")

    return app

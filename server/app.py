"""The FastAPI application: ``create_app(settings)``.

REST under ``/v1`` (motion spaces, datasets, jobs), the WebSocket stream at ``/v1/stream``, the
browser client at ``/``. Nothing happens at import time; ``morphspace serve`` (or uvicorn's
``--factory server.app:create_app``) builds the app.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import logging
import time
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request, WebSocket
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

from engine.blend.compiled import warm_up as warm_up_blends
from engine.graph.compiled import warm_up as warm_up_graphs
from engine.player_steps import warm_up as warm_up_steps
from server import __version__
from server.api import datasets, exports, graphs, jobs, spaces
from server.body_limit import BodyLimit
from server.frames import warm_up as warm_up_heads
from server.jobs import JobService
from server.graphs import GraphRegistry
from server.registry import SpaceRegistry
from server.scheduler import FrameScheduler
from server.settings import Settings
from server.stream import StreamSession, StreamStats
from server.workers.context import WorkerHeader, local_counters, server_counters

log = logging.getLogger("morphspace.server")
WEB_CLIENT = Path(__file__).resolve().parent.parent / "web_client" / "static"


def warm_up_stream():
    """Compile (or load from numba's cache) every compiled loop a stream runs: the blends, casts
    and solves (engine/blend/compiled.py), players' steps (engine/player_steps.py), frames' heads
    (server/frames.py), a motion graph's held feet and its transition search's played candidates
    (engine/graph/compiled.py)."""
    warm_up_blends()
    warm_up_steps()
    warm_up_heads()
    warm_up_graphs()


INPUT_ECHO = 200  # characters of a refused value's JSON that a 422 repeats


def short_input(error):
    """A validation error (a dict) whose ``input``, when its JSON is longer than ``INPUT_ECHO``
    characters, is replaced by that much of it and the full length."""
    value = error.get("input")
    text = json.dumps(value, separators=(",", ":"), default=str)
    if len(text) > INPUT_ECHO:
        error = {**error, "input": f"{text[:INPUT_ECHO]}... ({len(text)} characters)"}
    return error


def create_app(settings: Settings | None = None, worker=None) -> FastAPI:
    """The morphspace server for ``settings`` (default: from the environment).

    ``worker``: a server.workers.context.WorkerContext when this is one of several processes
    (``morphspace serve --workers N``): it publishes its counters for the others, /v1/health
    reports all of them, and only worker 0 runs the job queue.
    """
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app):
        for directory in (settings.data_dir, settings.spaces_dir, settings.datasets_dir, settings.work_dir):
            directory.mkdir(parents=True, exist_ok=True)
        await app.state.jobs.start()
        # the stream's compiled loops, loaded from numba's cache (compiled the first time: a few
        # seconds) before the first client, not in the middle of its first frames
        await asyncio.to_thread(warm_up_stream)
        publisher = stop_listening = None
        if worker is not None:
            publisher = asyncio.create_task(worker.publish_forever(lambda: local_counters(app.state)))
            if worker.runs_jobs:
                stop_listening = worker.on_wake(asyncio.get_running_loop(), app.state.jobs.wake)
        # Everything loaded so far lives as long as the server: keep it out of the cyclic
        # collector's full passes, which otherwise stall the event loop (and every stream) for
        # ~100 ms now and then (the registry does the same after opening a space).
        gc.freeze()
        try:
            yield
        finally:
            if stop_listening is not None:
                stop_listening()
            if publisher is not None:
                publisher.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await publisher
            await app.state.jobs.stop()
            app.state.frame_scheduler.close()
            app.state.registry.close()

    app = FastAPI(title="morphspace", version=__version__, lifespan=lifespan,
                  description="Motion spaces from 4D performance capture: REST for spaces, datasets and jobs; "
                              "a WebSocket stream of blended frames at /v1/stream (see docs/protocol.md).")
    app.state.settings = settings
    app.state.worker = worker
    app.state.started_at = time.time()
    app.state.registry = SpaceRegistry(settings.spaces_dir, derived=settings.derived_dir)
    app.state.graphs = GraphRegistry(app.state.registry)
    app.state.stream_stats = StreamStats()
    app.state.frame_scheduler = FrameScheduler()
    app.state.jobs = JobService(settings, app.state.registry, runs_jobs=worker is None or worker.runs_jobs,
                                wake_owner=worker.wake_jobs if worker is not None else None)
    app.add_middleware(BodyLimit, limit=settings.max_json_bytes)
    if worker is not None:
        app.add_middleware(WorkerHeader, index=worker.index)
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["*"],
                           allow_headers=["Authorization", "Content-Type"])

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request, exc):
        # FastAPI's 422, with each error's ``input`` cut to its first INPUT_ECHO characters of JSON:
        # a request of 200,000 sources is not sent back whole
        return JSONResponse(status_code=422, content={"detail": [short_input(e) for e in jsonable_encoder(exc.errors())]})

    app.include_router(spaces.router, prefix="/v1")
    app.include_router(graphs.router, prefix="/v1")
    app.include_router(datasets.router, prefix="/v1")
    app.include_router(jobs.router, prefix="/v1")
    app.include_router(exports.router, prefix="/v1")

    @app.get("/v1/health", tags=["server"], summary="Liveness and counters of every worker process")
    def health():
        workers, totals, restarts = server_counters(app.state)
        return {"status": "ok" if all(w["alive"] for w in workers) else "degraded", "version": __version__,
                "spaces": len(app.state.registry.names()), "connections": totals.get("connections", 0),
                "frames_sent": totals.get("frames_sent", 0), "frames_dropped": totals.get("frames_dropped", 0),
                "stream_errors": totals.get("stream_errors", 0), "scheduler": totals.get("scheduler", {}),
                "worker": worker.index if worker is not None else 0, "restarts": restarts, "workers": workers,
                "jobs": app.state.jobs.executor_status()}

    @app.websocket("/v1/stream")
    async def stream(websocket: WebSocket):
        await StreamSession(websocket, app.state.registry, settings, app.state.stream_stats,
                            app.state.frame_scheduler, graphs=app.state.graphs).run()

    if WEB_CLIENT.is_dir():
        app.mount("/app", StaticFiles(directory=WEB_CLIENT, html=True), name="web_client")

        @app.get("/", include_in_schema=False)
        def index(request: Request):
            # the query is the page's state (?space=reach&mode=linear...): a shared link keeps it
            query = request.url.query
            return RedirectResponse(f"/app/?{query}" if query else "/app/")

    return app

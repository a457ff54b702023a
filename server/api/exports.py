"""Exports: a clip of a space, or a graph's recorded performance, as glTF, USD, an OBJ / PLY sequence
or a vertex-animation texture, at once (short ones) or as a job's file."""

from __future__ import annotations

import asyncio
import re
from typing import Annotated

from fastapi import APIRouter, Body, HTTPException, Request, Response
from fastapi.responses import FileResponse

from engine.export import ClipError, check_clip
from server.api.deps import Authorised, RegistryDep, SettingsDep
from server.api.spaces import _space_or_404
from server.exports import MEDIA_TYPE, SUFFIX, ExportBlenders, clip_of
from server.graph_exports import GraphExports, check_graph_export
from server.jobs.models import ExportSpec, GraphExportSpec

router = APIRouter(tags=["exports"])
FILE = re.compile(r"^[0-9a-f]{16}\.(glb|usd|zip)$")
MEDIA_BY_SUFFIX = {".glb": "model/gltf-binary", ".usd": "application/octet-stream", ".zip": "application/zip"}

EXAMPLE = {"format": "glb", "params": {"speed": 1.3}, "track": [{"time": 2.0, "params": {"speed": 2.5}}],
           "duration": 4.0, "rate": 60}


def _blenders(request):
    blenders = getattr(request.app.state, "export_blenders", None)
    if blenders is None:
        blenders = request.app.state.export_blenders = ExportBlenders()
    return blenders


@router.post("/spaces/{name}/export", summary="Export a short clip now (glTF, USD, OBJ / PLY zip)",
             response_class=Response,
             responses={200: {"content": {"model/gltf-binary": {}, "application/octet-stream": {}, "application/zip": {}},
                              "description": "the file (Content-Disposition: attachment)"},
                        404: {"description": "no such space"},
                        422: {"description": "bad clip (the message names the field), or too long for a "
                                             "synchronous export (queue an export job)"}})
async def export_now(name: str, registry: RegistryDep, settings: SettingsDep, request: Request,
                     spec: Annotated[ExportSpec, Body(openapi_examples={"walk": {"value": EXAMPLE}})]):
    space = await asyncio.to_thread(_space_or_404, registry.get, name)
    values = spec.model_dump()
    clip = clip_of(values)
    try:
        check_clip(space, clip)
    except ClipError as exc:
        raise HTTPException(422, str(exc)) from None
    limit = settings.export_sync_max_vertex_frames
    if clip.n_frames * space.n_vertices > limit:
        raise HTTPException(422, f"{clip.n_frames} frames x {space.n_vertices} vertices is too long to export "
                                 f"synchronously (at most {limit:,} vertex-frames, {limit // space.n_vertices} frames "
                                 f"of {name}); queue it as a job: POST /v1/jobs with "
                                 f"{{\"kind\": \"export\", \"space\": \"{name}\", ...the same fields}}")
    data, stats, notes, seconds = await asyncio.to_thread(_blenders(request).export_bytes, space, values,
                                                          settings.work_dir / "exports")
    headers = {"Content-Disposition": f'attachment; filename="{name}{SUFFIX[spec.format]}"',
               "X-Morphspace-Frames": str(stats["frames"]), "X-Morphspace-Seconds": f"{seconds:.3f}"}
    if notes:
        headers["X-Morphspace-Notes"] = "; ".join(notes)[:1000]
    return Response(data, media_type=MEDIA_TYPE[spec.format], headers=headers)


def _graph_exports(request):
    exports = getattr(request.app.state, "graph_exports", None)
    if exports is None:
        exports = request.app.state.graph_exports = GraphExports()
    return exports


@router.post("/graphs/{name}/export", summary="Export a recorded graph performance now (glTF, USD, zips)",
             response_class=Response,
             responses={200: {"content": {"model/gltf-binary": {}, "application/octet-stream": {}, "application/zip": {}},
                              "description": "the file (Content-Disposition: attachment)"},
                        404: {"description": "no such graph"},
                        409: {"description": "the graph cannot be used (a space missing or rebuilt)"},
                        422: {"description": "not a recording of this graph (the message names the problem), or "
                                             "too long for a synchronous export (queue an export job)"}})
async def export_graph_now(name: str, settings: SettingsDep, request: Request, spec: GraphExportSpec):
    graphs = request.app.state.graphs
    graph, n_frames = await asyncio.to_thread(check_graph_export, graphs, name, spec.recording, HTTPException)
    n_vertices = graph.nodes[0].space.n_vertices
    limit = settings.export_sync_max_vertex_frames
    if n_frames * n_vertices > limit:
        raise HTTPException(422, f"{n_frames} frames x {n_vertices} vertices is too long to export synchronously "
                                 f"(at most {limit:,} vertex-frames, {limit // n_vertices} frames of {name}); queue "
                                 f"it as a job: POST /v1/jobs with {{\"kind\": \"export\", \"graph\": \"{name}\", "
                                 f"\"recording\": ..., \"format\": ...}}")
    data, stats, notes, digest, seconds = await asyncio.to_thread(
        _graph_exports(request).export_bytes, graph, spec.model_dump(), settings.work_dir / "exports")
    headers = {"Content-Disposition": f'attachment; filename="{name}{SUFFIX[spec.format]}"',
               "X-Morphspace-Frames": str(stats["frames"]), "X-Morphspace-Seconds": f"{seconds:.3f}",
               "X-Morphspace-Frames-Sha256": digest}
    if notes:
        headers["X-Morphspace-Notes"] = "; ".join(notes)[:1000]
    return Response(data, media_type=MEDIA_TYPE[spec.format], headers=headers)


def _export_path(settings, file):
    if not FILE.match(file):
        raise HTTPException(404, f"no export {file!r} (exports are named <job id>.glb, .usd or .zip)")
    path = settings.data_dir / "exports" / file
    if not path.is_file():
        raise HTTPException(404, f"no export {file!r}")
    return path


@router.get("/exports/{file}", summary="Download an export job's file", response_class=FileResponse,
            responses={200: {"content": {"model/gltf-binary": {}, "application/octet-stream": {},
                                         "application/zip": {}}},
                       404: {"description": "no such export"}})
def download_export(file: str, settings: SettingsDep):
    path = _export_path(settings, file)
    return FileResponse(path, media_type=MEDIA_BY_SUFFIX[path.suffix], filename=file)


@router.delete("/exports/{file}", status_code=204, dependencies=[Authorised], summary="Delete an export job's file",
               responses={401: {"description": "a bearer token is required"}, 404: {"description": "no such export"}})
def delete_export(file: str, settings: SettingsDep):
    _export_path(settings, file).unlink(missing_ok=True)
    return Response(status_code=204)

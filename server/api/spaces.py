"""Motion spaces: list, describe, and one frame at given parameters and time (OBJ, GLB or JSON)."""

from __future__ import annotations

import asyncio
import math
from enum import Enum
from typing import Annotated, Any

import numpy as np
import trimesh
from fastapi import APIRouter, HTTPException, Query, Response
from pydantic import BaseModel, Field

from engine.rotations import rot_y
from server.api.deps import RegistryDep
from server.registry import BrokenSpace, UnknownSpace

router = APIRouter(tags=["motion spaces"])


class ParameterInfo(BaseModel):
    name: str
    unit: str
    min: float
    max: float
    default: float


class SourceInfo(BaseModel):
    name: str
    duration: float = Field(description="seconds of one cycle (or the clip)")


class SpaceInfo(BaseModel):
    name: str
    playable: bool = Field(description="has a parameter map (can be streamed and steered)")
    cyclic: bool
    n_vertices: int
    n_faces: int
    n_phases: int
    model_size: float = Field(description="largest extent of the rest mesh (m)")
    epsilon: float = Field(description="hybrid blending error bound (m)")
    sources: list[SourceInfo]
    parameters: list[ParameterInfo]
    layout: str | None
    modes: list[str]
    bounds: list[list[float]] = Field(description="root-local box of the 16-bit codec (m)")
    file_bytes: int


class SpaceProblem(BaseModel):
    name: str
    error: str


class SpaceList(BaseModel):
    spaces: list[SpaceInfo]
    unreadable: list[SpaceProblem] = Field(description="files in the spaces directory that cannot be read")


class FrameFormat(str, Enum):
    obj = "obj"
    glb = "glb"
    json = "json"


class BlendMode(str, Enum):
    linear = "linear"
    hybrid = "hybrid"
    nonlinear = "nonlinear"


class FrameJSON(BaseModel):
    space: str
    mode: str
    time: float
    phase: float
    weights: list[float]
    requested: dict[str, float]
    realised: dict[str, float]
    clamped: bool
    message: str
    root: list[float] = Field(description="root position (m)")
    heading: float = Field(description="radians about +Y")
    placed: bool = Field(description="vertices are in world coordinates (root applied)")
    vertices: list[list[float]]
    faces: list[list[int]]


def _space_or_404(lookup, name):
    """``lookup(name)`` (the registry's get or describe), its errors as 404 / 409."""
    try:
        return lookup(name)
    except UnknownSpace as exc:
        raise HTTPException(404, str(exc)) from None
    except BrokenSpace as exc:
        raise HTTPException(409, str(exc)) from None


@router.get("/spaces", response_model=SpaceList, summary="List the motion spaces")
def list_spaces(registry: RegistryDep):
    spaces, problems = [], []
    for name in registry.names():
        try:
            spaces.append(registry.describe(name))
        except (UnknownSpace, BrokenSpace) as exc:
            problems.append({"name": name, "error": str(exc)})
    return {"spaces": spaces, "unreadable": problems}


@router.get("/spaces/{name}", response_model=SpaceInfo, summary="Describe one motion space",
            responses={404: {"description": "no such space"}, 409: {"description": "the file cannot be read"}})
def describe_space(name: str, registry: RegistryDep):
    return _space_or_404(registry.describe, name)


def parse_params(text, names):
    """{name: value} from ``"speed:1.5,turn_rate:-10"``; errors name the bad part."""
    out = {}
    for part in filter(None, (p.strip() for p in (text or "").split(","))):
        key, sep, value = part.partition(":")
        if not sep:
            raise HTTPException(422, f"params: expected name:value pairs separated by commas, got {part!r}")
        key = key.strip()
        if key not in names:
            raise HTTPException(422, f"params: unknown parameter {key!r}; this space has {', '.join(names)}")
        try:
            number = float(value)
        except ValueError:
            raise HTTPException(422, f"params: {key} must be a number, got {value.strip()!r}") from None
        if not math.isfinite(number):
            raise HTTPException(422, f"params: {key} must be finite, got {value.strip()}")
        out[key] = number
    return out


@router.get("/spaces/{name}/frame", summary="One frame at given parameters and time",
            response_model=FrameJSON,
            responses={200: {"content": {"model/obj": {}, "model/gltf-binary": {}},
                             "description": "the frame as OBJ, GLB or JSON"},
                       404: {"description": "no such space"}, 422: {"description": "bad parameters"}})
async def space_frame(
    name: str, registry: RegistryDep,
    params: Annotated[str, Query(description="comma-separated name:value pairs, e.g. speed:1.5,turn_rate:10; "
                                             "missing ones take the middle of their range")] = "",
    time: Annotated[float | None, Query(ge=0, le=86400, description="seconds from the start (root path included)")] = None,
    phase: Annotated[float | None, Query(ge=0, le=1, description="or the phase in [0, 1] (root at the origin)")] = None,
    mode: BlendMode = BlendMode.hybrid,
    format: FrameFormat = FrameFormat.obj,
    placed: Annotated[bool, Query(description="apply the root transform (world coordinates)")] = True,
) -> Any:
    space = await asyncio.to_thread(_space_or_404, registry.get, name)
    pmap = space.parameter_map
    if pmap is None:
        raise HTTPException(409, f"{name} has no parameter map; rebuild it from a spec with parameters")
    if time is not None and phase is not None:
        raise HTTPException(422, "give time or phase, not both")
    request = np.array([(lo + hi) / 2 for lo, hi in pmap.domain()])
    for key, value in parse_params(params, pmap.names).items():
        request[pmap.names.index(key)] = value
    solution = pmap.solve(request)
    w = solution.weights
    track = space.root_track
    if phase is None:
        root, heading, phase_ = track.after(w, time or 0.0)
        seconds = time or 0.0
    else:
        phase_ = phase % 1.0 if space.cyclic and phase < 1.0 else phase
        root, heading, seconds = np.zeros(3), 0.0, phase_ * track.duration(w)
    # The blenders keep scratch buffers and the streams use them on the event loop: blend there
    # too (after building the blender, which for the non-linear mode factorises, in a thread).
    await asyncio.to_thread(space.blender, mode.value)
    V = np.asarray(space.blend(w, phase_, mode.value), dtype=np.float64)
    if placed:
        V = V @ rot_y(heading).T + root
    F = np.asarray(space.faces)
    headers = {"X-Morphspace-Phase": f"{phase_:.6f}", "X-Morphspace-Clamped": str(solution.clamped).lower()}
    if format is FrameFormat.json:
        return FrameJSON(space=name, mode=mode.value, time=seconds, phase=phase_, weights=w.tolist(),
                         requested=dict(zip(pmap.names, request.tolist())),
                         realised=dict(zip(pmap.names, solution.realised.tolist())), clamped=solution.clamped,
                         message=solution.message, root=root.tolist(), heading=float(heading), placed=placed,
                         vertices=V.round(6).tolist(), faces=F.tolist())
    mesh = trimesh.Trimesh(V, F, process=False)
    if format is FrameFormat.obj:
        body = await asyncio.to_thread(mesh.export, file_type="obj", include_normals=False, include_texture=False)
        return Response(body, media_type="model/obj", headers=headers)
    body = await asyncio.to_thread(mesh.export, file_type="glb")
    return Response(body, media_type="model/gltf-binary", headers=headers)

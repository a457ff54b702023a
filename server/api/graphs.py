"""Motion graphs: list and describe the ``.mgraph`` files beside the spaces (streamed over
``/v1/stream`` by a hello naming ``graph``; docs/protocol.md)."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, HTTPException, Request
from pydantic import BaseModel, Field

from server.api.spaces import ParameterInfo
from server.graphs import BrokenGraph, UnknownGraph

router = APIRouter(tags=["motion graphs"])


class NodeInfo(BaseModel):
    name: str
    space: str = Field(description="the node's motion space (a name under GET /v1/spaces when it is beside the graph)")
    cyclic: bool
    return_to: str | None = Field(description="a one-shot's cyclic node it returns to by itself")
    duration: float = Field(description="seconds of one cycle (or the clip) at the space's first weight sample")
    parameters: list[ParameterInfo]


class EdgeInfo(BaseModel):
    from_: str = Field(alias="from", serialization_alias="from")
    to: str


class GraphInfo(BaseModel):
    name: str = Field(description="the file's name (what a stream's hello names)")
    graph: str = Field(description="the name the graph was built with")
    start: str = Field(description="the node a stream starts at unless its hello names one")
    nodes: list[NodeInfo]
    edges: list[EdgeInfo]
    n_vertices: int
    model_size: float = Field(description="largest extent of the rest mesh (m)")
    file_bytes: int
    checksum: str = Field(description="the file's header checksum (a graph recording names it: graph_checksum)")


class GraphProblem(BaseModel):
    name: str
    error: str


class GraphList(BaseModel):
    graphs: list[GraphInfo]
    unreadable: list[GraphProblem] = Field(description="graph files that cannot be used (not a graph, a space "
                                                       "missing or rebuilt since)")


def _graphs(request: Request):
    return request.app.state.graphs


def _describe_all(graphs):
    found, problems = [], []
    for name in graphs.names():
        try:
            found.append(graphs.describe(name))
        except (UnknownGraph, BrokenGraph) as exc:
            problems.append({"name": name, "error": str(exc)})
    return {"graphs": found, "unreadable": problems}


@router.get("/graphs", response_model=GraphList, response_model_by_alias=True, summary="List the motion graphs")
async def list_graphs(request: Request):
    return await asyncio.to_thread(_describe_all, _graphs(request))


@router.get("/graphs/{name}", response_model=GraphInfo, response_model_by_alias=True,
            summary="Describe one motion graph",
            responses={404: {"description": "no such graph"}, 409: {"description": "the graph cannot be used"}})
async def describe_graph(name: str, request: Request):
    try:
        return await asyncio.to_thread(_graphs(request).describe, name)
    except UnknownGraph as exc:
        raise HTTPException(404, str(exc)) from None
    except BrokenGraph as exc:
        raise HTTPException(409, str(exc)) from None

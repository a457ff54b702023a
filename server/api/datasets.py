"""Capture datasets: upload (zip or multipart), list, describe, delete (server/uploads/ does the work)."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field

from server import uploads
from server.api.deps import Authorised, SettingsDep, get_jobs

router = APIRouter(tags=["datasets"])
JobsDep = Annotated[object, Depends(get_jobs)]


class SequenceInfo(BaseModel):
    name: str
    frames: int = Field(description="frames of the sequence (consistent ones when it has both kinds)")
    consistent_frames: int = Field(description="frames sharing one mesh structure (buildable)")
    unstructured_frames: int = Field(description="frames with a mesh each (to be aligned)")
    fps: float | None
    cyclic: bool
    vertices: int | None = Field(description="vertices per frame when consistent")


class DatasetInfo(BaseModel):
    name: str
    kind: str = Field(description="uploaded, aligned (written by an align job) or capture")
    created: float = Field(description="Unix seconds")
    sequences: list[SequenceInfo]
    templates: list[str] = Field(description="rest meshes in template/")
    frames: int
    bytes: int
    buildable: list[str] = Field(description="sequences a build job can use (consistent frames)")
    pictures: list[str] = Field(description="alignment pictures the dataset has (GET .../pictures/{picture})")


class DatasetProblem(BaseModel):
    name: str
    error: str


class DatasetList(BaseModel):
    datasets: list[DatasetInfo]
    unreadable: list[DatasetProblem]


def _http(exc):
    return HTTPException(exc.status, exc.message)


UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "description": "a zip archive, or multipart/form-data whose parts are files named by their path in the "
                       "dataset (walk/frame_0001.obj, walk/meta.json, ...); layouts in docs/rest.md",
        "content": {
            "application/zip": {"schema": {"type": "string", "format": "binary"}},
            "multipart/form-data": {"schema": {"type": "object", "properties": {
                "files": {"type": "array", "items": {"type": "string", "format": "binary"}}}}},
        },
    }
}
UPLOAD_ERRORS = {
    400: {"description": "not a zip, malformed multipart, a path with '..' or absolute, a symlink, duplicate files"},
    401: {"description": "a bearer token is required"},
    409: {"description": "a dataset of that name exists (replace=true), or a job is using it"},
    413: {"description": "over the byte, file-count or unpacked-size limit, or a zip-bomb compression ratio"},
    415: {"description": "neither application/zip nor multipart/form-data"},
    422: {"description": "an unreadable frame, an unsupported file type, a bad meta.json or name"},
}


@router.post("/datasets", status_code=201, response_model=DatasetInfo, dependencies=[Authorised],
             summary="Upload a capture dataset (zip or multipart)", openapi_extra=UPLOAD_BODY,
             responses=UPLOAD_ERRORS)
async def upload_dataset(
    request: Request, settings: SettingsDep, jobs: JobsDep, response: Response,
    name: Annotated[str, Query(pattern=uploads.NAME.pattern, description="dataset name")],
    fps: Annotated[float, Query(gt=0, le=1000, description="frame rate of sequences without meta.json")] = 30.0,
    cyclic: Annotated[bool, Query(description="sequences without meta.json are cyclic")] = False,
    replace: Annotated[bool, Query(description="replace an existing dataset of that name")] = False,
):
    try:
        info = await uploads.receive_dataset(request, settings, name=name, fps=fps, cyclic=cyclic, replace=replace,
                                             busy=jobs.dataset_in_use)
    except uploads.UploadError as exc:
        raise _http(exc) from None
    response.headers["Location"] = f"/v1/datasets/{name}"
    return info


@router.get("/datasets", response_model=DatasetList, summary="List the datasets")
def list_datasets(settings: SettingsDep):
    datasets, problems = [], []
    for name in uploads.dataset_names(settings):
        try:
            datasets.append(uploads.describe_dataset(settings, name))
        except uploads.UploadError as exc:
            problems.append({"name": name, "error": exc.message})
    return {"datasets": datasets, "unreadable": problems}


@router.get("/datasets/{name}", response_model=DatasetInfo, summary="Describe one dataset",
            responses={404: {"description": "no such dataset"}, 409: {"description": "no readable manifest"}})
def describe_dataset(name: str, settings: SettingsDep):
    try:
        return uploads.describe_dataset(settings, name)
    except uploads.UploadError as exc:
        raise _http(exc) from None


@router.get("/datasets/{name}/pictures/{picture}", response_class=FileResponse,
            summary="One of an aligned dataset's pictures (PNG)",
            responses={200: {"content": {"image/png": {}}}, 404: {"description": "no such dataset or picture"}})
def dataset_picture(name: str, picture: str, settings: SettingsDep):
    try:
        path = uploads.picture_path(settings, name, picture)
    except uploads.UploadError as exc:
        raise _http(exc) from None
    return FileResponse(path, media_type="image/png")


@router.delete("/datasets/{name}", status_code=204, dependencies=[Authorised], summary="Delete a dataset",
               responses={404: {"description": "no such dataset"}, 409: {"description": "a job is using it"}})
async def delete_dataset(name: str, settings: SettingsDep, jobs: JobsDep):
    try:
        path = uploads.dataset_path(settings, name)
    except uploads.UploadError:
        raise HTTPException(404, f"no dataset {name!r}") from None
    if not path.is_dir():
        raise HTTPException(404, f"no dataset {name!r}")
    if jobs.dataset_in_use(name):
        raise HTTPException(409, f"dataset {name!r} is used by a queued or running job; cancel it first")
    try:
        await asyncio.to_thread(uploads.remove_dir, path)
    except FileNotFoundError:
        raise HTTPException(404, f"no dataset {name!r}") from None
    return Response(status_code=204)

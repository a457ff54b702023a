"""The whole upload: ``receive_dataset`` streams the body to a staging directory, extracts it,
assembles and validates the dataset, and publishes it (or removes the staging directory)."""

from __future__ import annotations

import asyncio
import os
import shutil
import uuid

from server.uploads.assemble import assemble_dataset
from server.uploads.extract import extract_multipart, extract_zip
from server.uploads.rules import STAGING_PREFIX, Limits, UploadError, dataset_path
from server.uploads.store import describe_dataset, publish_dir


async def receive_body(request, path, limits):
    """Stream the request body to ``path``; 413 as soon as it passes ``limits.max_bytes``."""
    declared = request.headers.get("content-length")
    if declared is not None:
        try:
            declared = int(declared)
        except ValueError:
            raise UploadError(400, f"Content-Length {declared!r} is not a number") from None
        if declared > limits.max_bytes:
            raise UploadError(413, f"the upload is {declared} bytes; the limit is {limits.max_bytes} bytes "
                                   "(MORPHSPACE_MAX_UPLOAD_BYTES)")
    from starlette.requests import ClientDisconnect

    size = 0
    with open(path, "xb") as out:
        try:
            async for chunk in request.stream():
                size += len(chunk)
                if size > limits.max_bytes:
                    raise UploadError(413, f"the upload passed the limit of {limits.max_bytes} bytes "
                                           "(MORPHSPACE_MAX_UPLOAD_BYTES)")
                out.write(chunk)
        except ClientDisconnect:   # an answer nobody reads, and one log line instead of a traceback
            raise UploadError(400, f"the client disconnected after {size} bytes of the upload") from None
    if size == 0:
        raise UploadError(400, "the upload is empty: send a zip archive or multipart/form-data files")
    return size


ZIP_TYPES = ("application/zip", "application/x-zip-compressed", "application/x-zip", "application/octet-stream", "")


def _unpack(staging, content_type, target, name, limits, *, fps, cyclic, replace):
    media = content_type.split(";")[0].strip().lower()
    body = staging / "body"
    raw = staging / "raw"
    raw.mkdir()
    if media == "multipart/form-data":
        extracted = extract_multipart(body, content_type, raw, limits)
    elif media in ZIP_TYPES:
        with open(body, "rb") as fh:
            magic = fh.read(4)
        if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
            raise UploadError(400, f"the upload is not a zip archive (it starts with {magic!r}); send a zip or "
                                   "multipart/form-data files")
        extracted = extract_zip(body, raw, limits)
    else:
        raise UploadError(415, f"unsupported Content-Type {media!r}: send application/zip or multipart/form-data")
    body.unlink()
    dataset = assemble_dataset(extracted, staging / "dataset", name, fps=fps, cyclic=cyclic)
    publish_dir(dataset, target, replace=replace)


async def receive_dataset(request, settings, *, name, fps=30.0, cyclic=False, replace=False, busy=None):
    """Receive, check, validate and publish one dataset upload; returns its description.

    ``busy(name)`` says whether a queued or running job uses the dataset (then it cannot be replaced).
    """
    target = dataset_path(settings, name)
    if target.exists() and not replace:
        raise UploadError(409, f"dataset {name!r} already exists (pass replace=true to replace it)")
    if busy is not None and busy(name):  # reads it, or will write it as its output
        raise UploadError(409, f"dataset {name!r} is used by a queued or running job; it cannot be written now")
    limits = Limits.from_settings(settings)
    settings.datasets_dir.mkdir(parents=True, exist_ok=True)
    # the receiving process's id in the name: a server started after a crash removes the staging
    # of processes that are gone (server.uploads.store.clean_stale)
    staging = settings.datasets_dir / f"{STAGING_PREFIX}{os.getpid()}-{uuid.uuid4().hex[:12]}"
    staging.mkdir()
    try:
        await receive_body(request, staging / "body", limits)
        await asyncio.to_thread(_unpack, staging, request.headers.get("content-type", ""), target, name, limits,
                                fps=fps, cyclic=cyclic, replace=replace)
    finally:
        await asyncio.to_thread(shutil.rmtree, staging, True)
    return describe_dataset(settings, name)

"""From an uploaded body to checked files on disk: zip archives and multipart/form-data.

Every member's path is checked (``member_parts``: no absolute paths, ``..``, unusual characters,
too deep) and its type (``file_role``: mesh frames, their textures and meta.json only) before anything is
written; sizes, file counts and compression ratios are bounded by ``Limits`` while extracting.
The files land under a staging root as ``Extracted`` (relative name, path parts, path on disk).
"""

from __future__ import annotations

import re
import stat
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from engine.mesh_io import MESH_EXTENSIONS
from engine.mesh_io.texture import RESOURCE_SUFFIXES
from server.uploads.rules import (
    CHUNK,
    MAX_DEPTH,
    PART,
    ZIP_MAX_RATIO,
    ZIP_RATIO_FLOOR,
    UploadError,
)


def member_parts(name):
    """Path parts of an uploaded file's relative name, or None for a skipped (hidden) file.

    Raises UploadError(400) for absolute paths, drive letters, backslashes, '..' and empty parts,
    and 422 for names with unusual characters or too deep.
    """
    if not name or "\x00" in name:
        raise UploadError(400, f"{name!r}: empty or NUL in a file name")
    if "\\" in name:
        raise UploadError(400, f"{name}: backslash in a path; use '/' between folders")
    if name.startswith("/") or re.match(r"^[A-Za-z]:", name):
        raise UploadError(400, f"{name}: absolute paths are not allowed in an upload")
    parts = name.rstrip("/").split("/")
    if any(part in ("..", ".") for part in parts):
        raise UploadError(400, f"{name}: '..' or '.' in a path is not allowed (it could point outside the dataset)")
    if any(part == "" for part in parts):
        raise UploadError(400, f"{name}: empty folder name in the path")
    if any(part.startswith(".") or part == "__MACOSX" for part in parts):
        return None
    for part in parts:
        if not PART.match(part):
            raise UploadError(422, f"{name}: {part!r} has characters other than letters, digits, space and "
                                   "_ - . @ + = , ( ) (or is longer than 128)")
    if len(parts) > MAX_DEPTH:
        raise UploadError(422, f"{name}: {len(parts)} path parts deep (at most {MAX_DEPTH}, the file name included); "
                               "see the accepted layouts in docs/rest.md")
    return parts


def file_role(parts, name):
    """'mesh', 'json' or 'resource' (a frame's material library or texture); any other file type
    is refused (422)."""
    suffix = PurePosixPath(parts[-1]).suffix.lower()
    if suffix in MESH_EXTENSIONS:
        return "mesh"
    if suffix in RESOURCE_SUFFIXES:
        return "resource"
    if suffix == ".json":
        if parts[-1] not in ("meta.json", "manifest.json"):
            raise UploadError(422, f"{name}: unexpected JSON file; only <sequence>/meta.json and manifest.json are read")
        return "json"
    raise UploadError(422, f"{name}: unsupported file type {suffix or '(none)'!r}; a dataset holds mesh frames "
                           f"({', '.join(MESH_EXTENSIONS)}), their textures ({', '.join(RESOURCE_SUFFIXES)}), "
                           "meta.json and manifest.json files")


@dataclass
class Extracted:
    root: Path
    files: list = field(default_factory=list)  # (relative name, parts, path on disk)
    bytes: int = 0

    def add(self, name, parts, limits):
        path = self.target(parts)
        self.files.append((name, parts, path))
        if len(self.files) > limits.max_files:
            raise UploadError(413, f"more than {limits.max_files} files in the upload (MORPHSPACE_MAX_UPLOAD_FILES)")
        return path

    def target(self, parts):
        path = self.root.joinpath(*parts)
        if not path.resolve().is_relative_to(self.root.resolve()):  # belt and braces: parts are checked
            raise UploadError(400, f"{'/'.join(parts)}: resolves outside the dataset")
        return path


def _open_new(path, name):
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return open(path, "xb")
    except FileExistsError:
        raise UploadError(400, f"{name}: the same file appears twice in the upload") from None
    except (NotADirectoryError, IsADirectoryError):
        raise UploadError(400, f"{name}: a file and a folder have the same name") from None


def extract_zip(body, root, limits):
    """Check every member's name, type and declared size, then extract counting real bytes."""
    try:
        archive = zipfile.ZipFile(body)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, ValueError) as exc:
        raise UploadError(400, f"the upload is not a readable zip archive ({exc})") from None
    out = Extracted(root)
    with archive:
        infos = archive.infolist()
        if len(infos) > 2 * limits.max_files + 1000:
            raise UploadError(413, f"the zip has {len(infos)} entries; at most {limits.max_files} files are "
                                   "accepted (MORPHSPACE_MAX_UPLOAD_FILES)")
        members, declared = [], 0
        for info in infos:
            name = info.filename
            if stat.S_ISLNK(info.external_attr >> 16):
                raise UploadError(400, f"{name}: symbolic links are not allowed in an upload")
            parts = member_parts(name)
            if parts is None or info.is_dir():
                continue
            file_role(parts, name)
            if info.flag_bits & 0x1:
                raise UploadError(400, f"{name}: encrypted zip members are not supported")
            if info.file_size > ZIP_RATIO_FLOOR and info.file_size > ZIP_MAX_RATIO * max(info.compress_size, 1):
                raise UploadError(413, f"{name}: compression ratio {info.file_size / max(info.compress_size, 1):.0f}:1 "
                                       f"is over {ZIP_MAX_RATIO}:1 (refused as a likely zip bomb)")
            declared += info.file_size
            if declared > limits.max_unpacked:
                raise UploadError(413, f"the zip unpacks to more than {limits.max_unpacked} bytes "
                                       "(MORPHSPACE_MAX_UNPACKED_BYTES)")
            members.append((info, out.add(name, parts, limits)))
        for info, path in members:
            name = info.filename
            written = 0
            with _open_new(path, name) as dst:
                try:
                    with archive.open(info) as src:
                        while chunk := src.read(CHUNK):
                            written += len(chunk)
                            out.bytes += len(chunk)
                            if written > info.file_size:
                                raise UploadError(400, f"{name}: more data than the zip declares "
                                                       f"({info.file_size} bytes); refused as a zip bomb")
                            if out.bytes > limits.max_unpacked:
                                raise UploadError(413, f"the zip unpacks to more than {limits.max_unpacked} bytes "
                                                       "(MORPHSPACE_MAX_UNPACKED_BYTES)")
                            dst.write(chunk)
                except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as exc:
                    raise UploadError(400, f"{name}: cannot extract the zip member ({exc})") from None
    return out


def extract_multipart(body, content_type, root, limits):
    """Write each file part (named by its relative path) under ``root``; a lone .zip part is unzipped."""
    from python_multipart.multipart import MultipartParser, parse_options_header

    _, options = parse_options_header(content_type)
    boundary = options.get(b"boundary")
    if not boundary:
        raise UploadError(400, "multipart/form-data without a boundary")
    out = Extracted(root)
    state = {"headers": {}, "field": b"", "value": b"", "file": None, "parts": None, "name": None, "count": 0,
             "zip": None, "ended": False}

    def on_part_begin():
        state["headers"], state["file"], state["parts"] = {}, None, None

    def on_header_field(data, start, end):
        state["field"] += data[start:end]

    def on_header_value(data, start, end):
        state["value"] += data[start:end]

    def on_header_end():
        state["headers"][state["field"].decode("latin-1").lower()] = state["value"].decode("utf-8", "replace")
        state["field"], state["value"] = b"", b""

    def on_headers_finished():
        state["count"] += 1
        _, disposition = parse_options_header(state["headers"].get("content-disposition", ""))
        filename = disposition.get(b"filename")
        if filename is None:
            field_name = disposition.get(b"name", b"?").decode("utf-8", "replace")
            raise UploadError(400, f"form field {field_name!r} is not a file; every part must be a file whose "
                                   "filename is its path in the dataset (e.g. walk/frame_0001.obj)")
        name = filename.decode("utf-8", "replace")
        if name.lower().endswith(".zip") and "/" not in name:
            if state["count"] > 1 or state["zip"] is not None:
                raise UploadError(400, f"{name}: a zip must be the only part of a multipart upload")
            state["zip"] = root.parent / "nested.zip"
            state["name"], state["file"] = name, open(state["zip"], "xb")
            return
        if state["zip"] is not None:
            raise UploadError(400, f"{name}: a zip must be the only part of a multipart upload")
        parts = member_parts(name)
        state["name"] = name
        if parts is None:
            return  # hidden file: skipped
        file_role(parts, name)
        state["parts"] = parts
        state["file"] = _open_new(out.add(name, parts, limits), name)

    def on_part_data(data, start, end):
        if state["file"] is not None:
            out.bytes += end - start
            if out.bytes > limits.max_unpacked:
                raise UploadError(413, f"the upload has more than {limits.max_unpacked} bytes of files "
                                       "(MORPHSPACE_MAX_UNPACKED_BYTES)")
            state["file"].write(data[start:end])

    def on_part_end():
        if state["file"] is not None:
            state["file"].close()
            state["file"] = None

    def on_end():
        state["ended"] = True

    parser = MultipartParser(boundary, {
        "on_part_begin": on_part_begin, "on_header_field": on_header_field, "on_header_value": on_header_value,
        "on_header_end": on_header_end, "on_headers_finished": on_headers_finished,
        "on_part_data": on_part_data, "on_part_end": on_part_end, "on_end": on_end})
    try:
        with open(body, "rb") as src:
            while chunk := src.read(CHUNK):
                parser.write(chunk)
        parser.finalize()
    except UploadError:
        raise
    except Exception as exc:  # python-multipart raises its own parse errors (and ValueError)
        raise UploadError(400, f"malformed multipart/form-data body ({exc})") from None
    finally:
        if state["file"] is not None:
            state["file"].close()
    if state["count"] == 0:
        raise UploadError(400, "the multipart body has no parts")
    if not state["ended"]:   # a body cut short: its last part may be cut anywhere, even at a line's end
        last = f" (its last part, {state['name']}, may be cut short)" if state["name"] else ""
        raise UploadError(400, f"malformed multipart/form-data body: it ends before its closing boundary "
                               f"--{boundary.decode('latin-1')}--{last}; send the whole body")
    if state["zip"] is not None:
        return extract_zip(state["zip"], root, limits)
    return out

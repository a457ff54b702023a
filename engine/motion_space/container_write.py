"""Writing a `.mspace` container atomically: arrays streamed and checksummed, then renamed.

The byte layout is `container_format`'s; `container.Container` maps what is written here.
"""

from __future__ import annotations

import collections.abc
import json
import math
import os
from pathlib import Path

import numpy as np

from engine.mesh_io.atomic import atomic_write
from engine.motion_space.container_format import (
    CHECKSUM_ALGORITHM,
    CHECKSUM_SIZE,
    DTYPES,
    FORMAT_NAME,
    FORMAT_VERSION,
    HEADER_START,
    MAGIC,
    NAME_PATTERN,
    PREAMBLE,
    MotionSpaceError,
    align,
    blake2b,
)

_CHUNK_BYTES = 16 * 2**20
_PLACEHOLDER_CHECKSUM = "0" * (2 * CHECKSUM_SIZE)


def write_container(path, arrays, metadata):
    """Write named arrays and JSON metadata into one `.mspace` file, atomically.

    Parameters
    ----------
    path : str or os.PathLike         destination; missing parent directories are created
    arrays : mapping str -> array     names made of `A-Z a-z 0-9 _ . / -`; any shape (0-d and
                                      empty included) of a bool or numeric dtype (integers,
                                      floats, complex). Stored in C order, little-endian, in the
                                      mapping's order.
    metadata : dict                   JSON data: dict (str keys), list, tuple, str, int, finite
                                      float, bool, None; numpy scalars are converted. Tuples come
                                      back as lists.

    Returns
    -------
    path : pathlib.Path   the written file

    Raises
    ------
    MotionSpaceError   bad name, object/string/structured dtype, non-JSON or non-finite metadata
                       (checked before anything is written)
    OSError            the file system failed; the destination is then left untouched

    Notes
    -----
    Arrays are streamed to a hidden temporary file in the destination directory in chunks of
    about 16 MB (only one chunk is converted at a time), checksummed on the way, and the header
    is rewritten once the checksums are known. The temporary file is fsynced and renamed onto
    `path` with `os.replace`, then the directory is fsynced: a reader sees the old file or the
    complete new one, never a part, and a crash leaves at most a hidden `.NAME.*.tmp` file.
    """
    path = Path(path)
    if not isinstance(arrays, collections.abc.Mapping):
        raise MotionSpaceError(f"{path}: arrays must be a mapping of name -> array, "
                               f"got {type(arrays).__name__}")
    if not isinstance(metadata, dict):
        raise MotionSpaceError(f"{path}: metadata must be a dict, got {type(metadata).__name__}")
    prepared = [_prepare_array(path, name, value) for name, value in arrays.items()]
    metadata = _json_value(path, metadata, "metadata", ancestors=set())

    entries, data_start, file_size = _layout(metadata, prepared)
    header = _header_bytes(metadata, entries, file_size)

    with atomic_write(path) as file:  # (makes missing parent directories)
        file.write(_preamble_and_header(header))
        file.write(bytes(data_start - HEADER_START - len(header)))
        for (_, array, dtype), entry in zip(prepared, entries.values()):
            entry["checksum"] = _stream_array(file, array, dtype)
            file.write(bytes(align(entry["nbytes"]) - entry["nbytes"]))
        if file.tell() != file_size:
            raise AssertionError(f"wrote {file.tell()} bytes, laid out {file_size}")
        final_header = _header_bytes(metadata, entries, file_size)
        if len(final_header) != len(header):
            raise AssertionError("the header changed length when its checksums were filled in")
        file.seek(0)
        file.write(_preamble_and_header(final_header))
        file.flush()
        os.fsync(file.fileno())
    _fsync_directory(path.parent)
    return path


def _prepare_array(path, name, value):
    """Check one (name, array) pair; return (name, array, little-endian dtype)."""
    if not isinstance(name, str) or not name:
        raise MotionSpaceError(f"{path}: array names must be non-empty strings, got {name!r}")
    if not NAME_PATTERN.fullmatch(name):
        raise MotionSpaceError(
            f"{path}: array name {name!r} has characters other than A-Z a-z 0-9 _ . / -"
        )
    try:
        array = value if isinstance(value, np.ndarray) else np.asarray(value)
    except (TypeError, ValueError) as err:
        raise MotionSpaceError(f"{path}: array {name!r} is not an array: {err}") from None
    dtype = array.dtype
    if dtype.fields is None and dtype.subdtype is None and dtype.kind in "biufc":
        dtype = dtype.newbyteorder("<") if dtype.itemsize > 1 else dtype
    if dtype.str not in DTYPES:
        raise MotionSpaceError(
            f"{path}: array {name!r} has dtype {array.dtype} ({_describe_kind(array.dtype)}); "
            "only bool, integer, float (16, 32, 64 bit) and complex dtypes can be stored "
            "(nothing is pickled)"
        )
    return name, array, dtype


def _describe_kind(dtype):
    kinds = {"O": "Python objects", "U": "unicode strings", "S": "byte strings",
             "V": "raw or structured records", "M": "datetimes", "m": "timedeltas"}
    return kinds.get(dtype.kind, "not portable")


def _json_value(path, value, where, ancestors):
    """Return `value` as plain JSON data (tuples -> lists, numpy scalars -> Python); or raise."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            raise MotionSpaceError(
                f"{path}: {where} is {float(value)}; JSON metadata must be finite"
            )
        return float(value)
    if isinstance(value, (dict, list, tuple)):
        if id(value) in ancestors:
            raise MotionSpaceError(f"{path}: {where} contains itself")
        ancestors = ancestors | {id(value)}
        if isinstance(value, dict):
            result = {}
            for key, item in value.items():
                if not isinstance(key, str):
                    raise MotionSpaceError(
                        f"{path}: {where} has key {key!r} of type {type(key).__name__}; "
                        "metadata keys must be strings"
                    )
                result[key] = _json_value(path, item, f"{where}[{key!r}]", ancestors)
            return result
        return [_json_value(path, item, f"{where}[{i}]", ancestors) for i, item in enumerate(value)]
    hint = "; store arrays in `arrays`, not in metadata" if isinstance(value, np.ndarray) else ""
    raise MotionSpaceError(
        f"{path}: {where} has type {type(value).__name__}, which is not JSON (use dict, list, str, "
        f"int, float, bool or None){hint}"
    )


def _layout(metadata, prepared):
    """Place the arrays; return (header entries, offset of the first array, file size)."""
    data_start = align(HEADER_START)
    while True:
        entries, cursor = {}, data_start
        for name, array, dtype in prepared:
            nbytes = array.size * dtype.itemsize
            entries[name] = {"dtype": dtype.str, "shape": list(array.shape), "offset": cursor,
                             "nbytes": nbytes, "checksum": _PLACEHOLDER_CHECKSUM}
            cursor += align(nbytes)
        header = _header_bytes(metadata, entries, cursor)
        needed = align(HEADER_START + len(header))
        if needed <= data_start:
            return entries, data_start, cursor
        data_start = needed  # the header grew past the first array; lengths only grow, so this ends


def _header_bytes(metadata, entries, file_size):
    header = {"format": FORMAT_NAME, "version": FORMAT_VERSION,
              "checksum_algorithm": CHECKSUM_ALGORITHM, "file_size": file_size,
              "metadata": metadata, "arrays": entries}
    return json.dumps(header, ensure_ascii=False, allow_nan=False,
                      separators=(",", ":")).encode("utf-8")


def _preamble_and_header(header):
    preamble = PREAMBLE.pack(MAGIC, FORMAT_VERSION, len(header))
    return preamble + blake2b(preamble, header).digest() + header


def _stream_array(file, array, dtype):
    """Write `array` as `dtype` in C order, chunk by chunk; return the BLAKE2b-128 hex digest."""
    digest = blake2b()
    for chunk in _array_chunks(array, dtype):
        raw = chunk.reshape(-1).view(np.uint8)
        digest.update(raw)
        file.write(raw)
    return digest.hexdigest()


def _array_chunks(array, dtype):
    """Yield C-contiguous pieces of `array` in `dtype` (whole rows, about 16 MB each)."""
    if array.size == 0:
        return
    if array.ndim == 0:
        yield np.ascontiguousarray(array, dtype=dtype)
        return
    row_bytes = array[0].size * dtype.itemsize
    rows = max(1, _CHUNK_BYTES // row_bytes)
    for start in range(0, array.shape[0], rows):
        yield np.ascontiguousarray(array[start:start + rows], dtype=dtype)


def _fsync_directory(directory):
    """Make the rename durable (POSIX); platforms that cannot open directories skip it."""
    if not hasattr(os, "O_DIRECTORY"):
        return
    handle = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(handle)
    finally:
        os.close(handle)

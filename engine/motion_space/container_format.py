"""The `.mspace` container's byte layout: constants, errors, and reading and checking a header.

`container_write` writes a container, `container` maps one; both follow this layout.

Byte layout (all integers little-endian; docs/file-formats.md, "Motion space files"):

    offset 0    8 bytes   magic  b"\\x89MSPACE\\n"
    offset 8    u32       format version (1)
    offset 12   u64       header length H in bytes
    offset 20   16 bytes  header checksum: BLAKE2b-128 of bytes [0, 20) followed by the header
    offset 36   H bytes   header: UTF-8 JSON (format, version, checksum_algorithm, file_size,
                          metadata, arrays: {name: {dtype, shape, offset, nbytes, checksum}})
    zero padding to a multiple of 64, then every array's raw bytes (C order, little-endian),
    each starting at a multiple of 64 and followed by zero padding to the next multiple of 64.

Nothing is ever pickled: dtypes are restricted to bool and numeric types, metadata is plain JSON.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import struct

import numpy as np

MAGIC = b"\x89MSPACE\n"
FORMAT_NAME = "morphspace-motion-space"
FORMAT_VERSION = 1
CHECKSUM_ALGORITHM = "blake2b-128"
ALIGNMENT = 64

PREAMBLE = struct.Struct("<8sIQ")  # magic, version, header length
CHECKSUM_SIZE = 16
HEADER_START = PREAMBLE.size + CHECKSUM_SIZE  # 36
NAME_PATTERN = re.compile(r"[A-Za-z0-9_./-]+")
# Storable dtypes, as numpy spells them little-endian: bool, integers, IEEE floats, complex.
# (No long double: its bytes differ between platforms.)
DTYPES = ("|b1", "|u1", "|i1", "<u2", "<i2", "<u4", "<i4", "<u8", "<i8",
          "<f2", "<f4", "<f8", "<c8", "<c16")

# First bytes of files that are easily mistaken for a motion space, for a helpful message.
_KNOWN_SIGNATURES = {
    b"PK\x03\x04": "a zip archive (an .npz?)",
    b"\x93NUMPY": "a NumPy .npy file",
    b"\x89PNG": "a PNG image",
    b"\x80": "a Python pickle",
    b"{": "a JSON file",
}


class MotionSpaceError(ValueError):
    """A motion space file is missing, foreign, truncated, corrupt or cannot be written.

    Every message starts with the file it is about, then the problem.
    """


class MissingArrayError(MotionSpaceError, KeyError):
    """`container[name]` for a name the file does not hold (also a KeyError)."""

    def __str__(self):
        return str(self.args[0]) if self.args else ""


def open_for_reading(path):
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise MotionSpaceError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise MotionSpaceError(f"{path}: is a directory, not a motion space file") from None
    except OSError as err:
        raise MotionSpaceError(f"{path}: cannot open: {err.strerror or err}") from err


def read_header(path, file):
    """Read, check and parse the preamble and header of an open file; return the header dict.

    The returned dict also has `header_bytes` and `header_checksum` (hex).
    """
    size = os.fstat(file.fileno()).st_size
    start = file.read(HEADER_START)
    if len(start) < len(MAGIC) or not start.startswith(MAGIC):
        if MAGIC.startswith(start) and start:
            raise MotionSpaceError(f"{path}: truncated: the file has only {size} bytes")
        raise MotionSpaceError(f"{path}: not a motion space file ({_describe_foreign(start)})")
    if len(start) < HEADER_START:
        raise MotionSpaceError(
            f"{path}: truncated: the preamble needs {HEADER_START} bytes, file has {size}"
        )
    _, version, header_length = PREAMBLE.unpack_from(start)
    if version > FORMAT_VERSION:
        raise MotionSpaceError(
            f"{path}: format version {version} is newer than this morphspace supports "
            f"(up to {FORMAT_VERSION}); upgrade morphspace to read it"
        )
    if version < 1:
        raise MotionSpaceError(f"{path}: unknown format version {version}")
    header_end = HEADER_START + header_length
    if header_end > size:
        raise MotionSpaceError(
            f"{path}: truncated: the header needs {header_end} bytes, file has {size}"
        )
    raw = file.read(header_length)
    stored_checksum = start[PREAMBLE.size:HEADER_START]
    actual_checksum = blake2b(start[:PREAMBLE.size], raw).digest()
    if actual_checksum != stored_checksum:
        raise MotionSpaceError(
            f"{path}: the header is corrupt: checksum {actual_checksum.hex()} does not match "
            f"the stored {stored_checksum.hex()}"
        )
    try:
        header = json.loads(raw.decode("utf-8"), object_pairs_hook=_unique_keys,
                            parse_constant=_reject_constant)
    except (UnicodeDecodeError, ValueError) as err:
        raise MotionSpaceError(f"{path}: malformed header: not UTF-8 JSON ({err})") from None
    _check_header(path, header, version, header_end)
    if header["file_size"] > size:
        raise MotionSpaceError(
            f"{path}: truncated: header says {header['file_size']} bytes, file has {size}"
        )
    if header["file_size"] < size:
        raise MotionSpaceError(
            f"{path}: unexpected trailing data: header says {header['file_size']} bytes, "
            f"file has {size}"
        )
    header["header_bytes"] = header_length
    header["header_checksum"] = stored_checksum.hex()
    return header


def _describe_foreign(start):
    if not start:
        return "the file is empty"
    for signature, description in _KNOWN_SIGNATURES.items():
        if start.startswith(signature):
            return f"it looks like {description}"
    return f"it starts with {start[:len(MAGIC)]!r}, expected {MAGIC!r}"


def _unique_keys(pairs):
    result = {}
    for key, value in pairs:
        if key in result:
            raise ValueError(f"duplicate key {key!r}")
        result[key] = value
    return result


def _reject_constant(name):
    raise ValueError(f"{name} is not allowed")


def _check_header(path, header, version, header_end):
    """Check the parsed header's structure and array placement; raise MotionSpaceError."""

    def bad(problem):
        return MotionSpaceError(f"{path}: malformed header: {problem}")

    if not isinstance(header, dict):
        raise bad("not a JSON object")
    expected = {"format": FORMAT_NAME, "version": version, "checksum_algorithm": CHECKSUM_ALGORITHM}
    for key, value in expected.items():
        if header.get(key) != value:
            raise bad(f"{key} is {header.get(key)!r}, expected {value!r}")
    if not isinstance(header.get("metadata"), dict):
        raise bad("metadata is not a JSON object")
    if not _is_count(header.get("file_size")):
        raise bad(f"file_size is {header.get('file_size')!r}")
    arrays = header.get("arrays")
    if not isinstance(arrays, dict):
        raise bad("arrays is not a JSON object")
    cursor = align(header_end)
    for name, entry in arrays.items():
        if not NAME_PATTERN.fullmatch(name):
            raise bad(f"array name {name!r} has characters other than A-Z a-z 0-9 _ . / -")
        _check_entry(name, entry, bad)
        if entry["offset"] < cursor:
            raise bad(f"array {name!r} at offset {entry['offset']} overlaps the header or the "
                      f"previous array (which end at {cursor})")
        cursor = entry["offset"] + entry["nbytes"]
    if cursor > header["file_size"]:
        raise bad(f"arrays end at byte {cursor}, past file_size {header['file_size']}")


def _check_entry(name, entry, bad):
    if not isinstance(entry, dict) or set(entry) != {"dtype", "shape", "offset", "nbytes",
                                                     "checksum"}:
        raise bad(f"array {name!r} needs exactly dtype, shape, offset, nbytes and checksum")
    dtype_str, shape = entry["dtype"], entry["shape"]
    if dtype_str not in DTYPES:
        raise bad(f"array {name!r} has unsupported dtype {dtype_str!r}")
    dtype = np.dtype(dtype_str)
    if not isinstance(shape, list) or len(shape) > 64 or not all(map(_is_count, shape)):
        raise bad(f"array {name!r} has invalid shape {shape!r}")
    if not _is_count(entry["offset"]) or entry["offset"] % ALIGNMENT:
        raise bad(f"array {name!r} has offset {entry['offset']!r}, not a multiple of {ALIGNMENT}")
    if entry["nbytes"] != math.prod(shape) * dtype.itemsize:
        raise bad(f"array {name!r} has nbytes {entry['nbytes']!r}, but shape {shape} of "
                  f"{dtype_str} needs {math.prod(shape) * dtype.itemsize}")
    checksum = entry["checksum"]
    if not isinstance(checksum, str) or not re.fullmatch(r"[0-9a-f]{32}", checksum):
        raise bad(f"array {name!r} has checksum {checksum!r}, expected 32 hex digits")


def _is_count(value):
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def align(offset):
    return -(-offset // ALIGNMENT) * ALIGNMENT


def blake2b(*parts):
    digest = hashlib.blake2b(digest_size=CHECKSUM_SIZE)
    for part in parts:
        digest.update(part)
    return digest

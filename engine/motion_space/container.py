"""The `.mspace` container: JSON metadata plus named numpy arrays in one memory-mapped file.

A motion space is stored as one self-describing, versioned, checksummed file. This module knows
nothing about motion spaces themselves (that is `space.py`); it stores and maps arrays.

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

import collections.abc
import contextlib
import hashlib
import json
import math
import mmap
import os
import re
import secrets
import struct
from pathlib import Path

import numpy as np

MAGIC = b"\x89MSPACE\n"
FORMAT_NAME = "morphspace-motion-space"
FORMAT_VERSION = 1
CHECKSUM_ALGORITHM = "blake2b-128"
ALIGNMENT = 64

_PREAMBLE = struct.Struct("<8sIQ")  # magic, version, header length
_CHECKSUM_SIZE = 16
_HEADER_START = _PREAMBLE.size + _CHECKSUM_SIZE  # 36
_NAME_PATTERN = re.compile(r"[A-Za-z0-9_./-]+")
# Storable dtypes, as numpy spells them little-endian: bool, integers, IEEE floats, complex.
# (No long double: its bytes differ between platforms.)
DTYPES = ("|b1", "|u1", "|i1", "<u2", "<i2", "<u4", "<i4", "<u8", "<i8",
          "<f2", "<f4", "<f8", "<c8", "<c16")
_CHUNK_BYTES = 16 * 2**20
_PLACEHOLDER_CHECKSUM = "0" * (2 * _CHECKSUM_SIZE)

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


# --------------------------------------------------------------------------------------------
# Writing


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

    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp_name = _create_temporary(path)
    try:
        with os.fdopen(handle, "wb") as file:
            file.write(_preamble_and_header(header))
            file.write(bytes(data_start - _HEADER_START - len(header)))
            for (_, array, dtype), entry in zip(prepared, entries.values()):
                entry["checksum"] = _stream_array(file, array, dtype)
                file.write(bytes(_align(entry["nbytes"]) - entry["nbytes"]))
            if file.tell() != file_size:
                raise AssertionError(f"wrote {file.tell()} bytes, laid out {file_size}")
            final_header = _header_bytes(metadata, entries, file_size)
            if len(final_header) != len(header):
                raise AssertionError("the header changed length when its checksums were filled in")
            file.seek(0)
            file.write(_preamble_and_header(final_header))
            file.flush()
            os.fsync(file.fileno())
        os.replace(temp_name, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp_name)
        raise
    _fsync_directory(path.parent)
    return path


def _prepare_array(path, name, value):
    """Check one (name, array) pair; return (name, array, little-endian dtype)."""
    if not isinstance(name, str) or not name:
        raise MotionSpaceError(f"{path}: array names must be non-empty strings, got {name!r}")
    if not _NAME_PATTERN.fullmatch(name):
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
    data_start = _align(_HEADER_START)
    while True:
        entries, cursor = {}, data_start
        for name, array, dtype in prepared:
            nbytes = array.size * dtype.itemsize
            entries[name] = {"dtype": dtype.str, "shape": list(array.shape), "offset": cursor,
                             "nbytes": nbytes, "checksum": _PLACEHOLDER_CHECKSUM}
            cursor += _align(nbytes)
        header = _header_bytes(metadata, entries, cursor)
        needed = _align(_HEADER_START + len(header))
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
    preamble = _PREAMBLE.pack(MAGIC, FORMAT_VERSION, len(header))
    return preamble + _blake2b(preamble, header).digest() + header


def _stream_array(file, array, dtype):
    """Write `array` as `dtype` in C order, chunk by chunk; return the BLAKE2b-128 hex digest."""
    digest = _blake2b()
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


def _create_temporary(path):
    """Create a new, empty, hidden file next to `path`; return (file descriptor, name)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    while True:
        name = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
        try:
            return os.open(name, flags, 0o666), name
        except FileExistsError:
            continue


def _fsync_directory(directory):
    """Make the rename durable (POSIX); platforms that cannot open directories skip it."""
    if not hasattr(os, "O_DIRECTORY"):
        return
    handle = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(handle)
    finally:
        os.close(handle)


# --------------------------------------------------------------------------------------------
# Reading


class Container(collections.abc.Mapping):
    """A read-only, memory-mapped `.mspace` file: `container[name]` is an array view.

    Open with `Container.open(path)`; use as a context manager or call `close()`.

    Attributes
    ----------
    path : pathlib.Path
    version : int          format version of the file
    checksum : str         the header's checksum (32 hex digits): it covers the metadata and
                           every array's checksum, so it names the file's content
    metadata : dict        the JSON metadata (this object's own copy)
    names : tuple of str   array names in file order

    Notes
    -----
    Arrays are `np.frombuffer` views onto a read-only mmap of the whole file: opening costs
    only the header (plus one checksum pass when `verify=True`), and pages are read by the
    operating system when touched. Views are read-only (`flags.writeable` is False) and stay
    valid after `close()`: the mapping is released when the last view is garbage collected.
    Files are replaced atomically, never modified in place, so a mapping stays consistent
    even when the file is rewritten while open.
    """

    def __init__(self, path, header, mapping):
        """Private: use `Container.open`."""
        self.path = path
        self.version = header["version"]
        self.checksum = header["header_checksum"]
        self.metadata = header["metadata"]
        self._entries = header["arrays"]
        self._file_size = header["file_size"]
        self._mmap = mapping
        self.names = tuple(self._entries)

    @classmethod
    def open(cls, path, *, verify=True):
        """Open and map a motion space file.

        Parameters
        ----------
        path : str or os.PathLike
        verify : bool   recompute every array's checksum now (reads the whole file once);
                        False opens a huge file instantly, and `verify()` can be called later

        Raises
        ------
        MotionSpaceError   missing file, not a motion space file, newer format version,
                           truncated file, trailing data, corrupt header or (verify) corrupt array
        """
        path = Path(path)
        with _open_for_reading(path) as file:
            header = _read_header(path, file)
            try:
                mapping = mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ)
            except (OSError, ValueError) as err:
                raise MotionSpaceError(f"{path}: cannot memory-map the file: {err}") from err
        if len(mapping) != header["file_size"]:  # changed between stat and mmap
            mapping.close()
            raise MotionSpaceError(f"{path}: the file changed size while being opened")
        container = cls(path, header, mapping)
        if verify:
            try:
                container.verify()
            except MotionSpaceError:
                container.close()
                raise
        return container

    # Mapping interface -------------------------------------------------------------------------

    def __getitem__(self, name):
        """Read-only view of array `name` (shape and dtype as written, little-endian)."""
        entry = self._entry(name)
        dtype = np.dtype(entry["dtype"])
        count = math.prod(entry["shape"])
        view = np.frombuffer(self._mapping(), dtype=dtype, count=count, offset=entry["offset"])
        return view.reshape(entry["shape"])

    def __iter__(self):
        return iter(self.names)

    def __len__(self):
        return len(self.names)

    def __contains__(self, name):
        return name in self._entries

    # Identity semantics (Mapping's __eq__ would compare arrays and make containers unhashable).
    __eq__ = object.__eq__
    __hash__ = object.__hash__

    # Other accessors ---------------------------------------------------------------------------

    def nbytes(self, name):
        """Size of array `name` in bytes (0 for empty arrays)."""
        return self._entry(name)["nbytes"]

    def dtype(self, name):
        """numpy dtype of array `name` (little-endian or byte-order free)."""
        return np.dtype(self._entry(name)["dtype"])

    def shape(self, name):
        """Shape tuple of array `name`."""
        return tuple(self._entry(name)["shape"])

    def verify(self, name=None):
        """Recompute the checksum of array `name`, or of every array; raise on a mismatch.

        Raises
        ------
        MotionSpaceError   naming the first corrupt array
        """
        mapping = self._mapping()
        for each in self.names if name is None else (name,):
            entry = self._entry(each)
            start, stop = entry["offset"], entry["offset"] + entry["nbytes"]
            with memoryview(mapping) as whole, whole[start:stop] as data:
                actual = _blake2b(data).hexdigest()
            if actual != entry["checksum"]:
                raise MotionSpaceError(
                    f"{self.path}: array {each!r} is corrupt: checksum {actual} does not match "
                    f"{entry['checksum']} in the header"
                )

    @property
    def closed(self):
        return self._mmap is None

    def close(self):
        """Release the mapping; views already handed out stay valid until they are dropped."""
        if self._mmap is None:
            return
        mapping, self._mmap = self._mmap, None
        # Views still exporting the buffer keep the mapping open (close() raises BufferError);
        # it is then unmapped when the last view is garbage collected.
        with contextlib.suppress(BufferError):
            mapping.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def __repr__(self):
        state = "closed" if self.closed else f"{len(self)} arrays, {self._file_size} bytes"
        return f"<Container {str(self.path)!r} ({state})>"

    def _entry(self, name):
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            available = ", ".join(repr(n) for n in self.names) or "none"
            raise MissingArrayError(
                f"{self.path}: no array named {name!r}; available: {available}"
            ) from None

    def _mapping(self):
        if self._mmap is None:
            raise MotionSpaceError(f"{self.path}: the container is closed")
        return self._mmap


def inspect_container(path):
    """Read and check a motion space file's header without mapping or reading the arrays.

    Returns
    -------
    summary : dict   JSON-serialisable: path, format, version, checksum_algorithm, file_size,
                     header_bytes, header_checksum (hex), metadata, and arrays as
                     {name: {dtype, shape, offset, nbytes, checksum}} in file order

    Raises
    ------
    MotionSpaceError   as `Container.open`, except that array checksums are not checked
    """
    path = Path(path)
    with _open_for_reading(path) as file:
        header = _read_header(path, file)
    summary = {"path": str(path)}
    summary.update(header)
    return summary


def _open_for_reading(path):
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise MotionSpaceError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise MotionSpaceError(f"{path}: is a directory, not a motion space file") from None
    except OSError as err:
        raise MotionSpaceError(f"{path}: cannot open: {err.strerror or err}") from err


def _read_header(path, file):
    """Read, check and parse the preamble and header of an open file; return the header dict.

    The returned dict also has `header_bytes` and `header_checksum` (hex).
    """
    size = os.fstat(file.fileno()).st_size
    start = file.read(_HEADER_START)
    if len(start) < len(MAGIC) or not start.startswith(MAGIC):
        if MAGIC.startswith(start) and start:
            raise MotionSpaceError(f"{path}: truncated: the file has only {size} bytes")
        raise MotionSpaceError(f"{path}: not a motion space file ({_describe_foreign(start)})")
    if len(start) < _HEADER_START:
        raise MotionSpaceError(
            f"{path}: truncated: the preamble needs {_HEADER_START} bytes, file has {size}"
        )
    _, version, header_length = _PREAMBLE.unpack_from(start)
    if version > FORMAT_VERSION:
        raise MotionSpaceError(
            f"{path}: format version {version} is newer than this morphspace supports "
            f"(up to {FORMAT_VERSION}); upgrade morphspace to read it"
        )
    if version < 1:
        raise MotionSpaceError(f"{path}: unknown format version {version}")
    header_end = _HEADER_START + header_length
    if header_end > size:
        raise MotionSpaceError(
            f"{path}: truncated: the header needs {header_end} bytes, file has {size}"
        )
    raw = file.read(header_length)
    stored_checksum = start[_PREAMBLE.size:_HEADER_START]
    actual_checksum = _blake2b(start[:_PREAMBLE.size], raw).digest()
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
    cursor = _align(header_end)
    for name, entry in arrays.items():
        if not _NAME_PATTERN.fullmatch(name):
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


# --------------------------------------------------------------------------------------------
# Shared


def _align(offset):
    return -(-offset // ALIGNMENT) * ALIGNMENT


def _blake2b(*parts):
    digest = hashlib.blake2b(digest_size=_CHECKSUM_SIZE)
    for part in parts:
        digest.update(part)
    return digest

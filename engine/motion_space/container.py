"""The `.mspace` container: JSON metadata plus named numpy arrays in one memory-mapped file.

A motion space is stored as one self-describing, versioned, checksummed file. These modules know
nothing about motion spaces themselves (that is `space.py`); they store and map arrays:
`container_format` is the byte layout (docs/file-formats.md, "Motion space files") and the
header's checks, `container_write` writes a file atomically, and this module maps one
(`Container`) or reads its header alone (`inspect_container`). The names other modules use are
all importable from here.

Nothing is ever pickled: dtypes are restricted to bool and numeric types, metadata is plain JSON.
"""

from __future__ import annotations

import collections.abc
import contextlib
import math
import mmap
from pathlib import Path

import numpy as np

from engine.motion_space.container_format import (
    ALIGNMENT,
    CHECKSUM_ALGORITHM,
    DTYPES,
    FORMAT_NAME,
    FORMAT_VERSION,
    MAGIC,
    MissingArrayError,
    MotionSpaceError,
    blake2b,
    open_for_reading,
    read_header,
)
from engine.motion_space.container_write import write_container

__all__ = ["ALIGNMENT", "CHECKSUM_ALGORITHM", "DTYPES", "FORMAT_NAME", "FORMAT_VERSION", "MAGIC", "Container",
           "MissingArrayError", "MotionSpaceError", "inspect_container", "write_container"]


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
        with open_for_reading(path) as file:
            header = read_header(path, file)
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
                actual = blake2b(data).hexdigest()
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
    with open_for_reading(path) as file:
        header = read_header(path, file)
    summary = {"path": str(path)}
    summary.update(header)
    return summary


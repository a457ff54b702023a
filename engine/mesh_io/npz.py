"""Compact single-file storage of a consistent-topology sequence as a NumPy .npz archive.

Layout (all plain arrays, loadable with ``np.load(path, allow_pickle=False)``):

=============  ========================  ==============================================
key            array                     contents
=============  ========================  ==============================================
``vertices``   (frames, n, 3) float32    positions per frame
``faces``      (m, 3) int32              shared triangles, 0-based
``colors``     (frames, n, 3) float32    optional, RGB in [0, 1]
``metadata``   0-d unicode string        JSON object, see below
any other      any non-object dtype      extra arrays given to `save_sequence_npz`
=============  ========================  ==============================================

The JSON object holds ``format`` ("morphspace.mesh_sequence"), ``version`` (1), ``names``
(frame names) and ``metadata`` (the JSON-compatible keyword arguments). Nothing is pickled.
"""

from __future__ import annotations

import json
import zipfile
import zlib

import numpy as np

from .atomic import atomic_write
from .errors import MeshFormatError, MeshValidationError
from .mesh import check_colors, check_faces
from .mesh_sequence import MeshSequence, check_sequence_vertices

FORMAT = "morphspace.mesh_sequence"
VERSION = 1
_RESERVED = {"vertices", "faces", "colors", "metadata"}


def save_sequence_npz(
    path, vertices, faces, *, colors=None, names=None, compress=False, **arrays_and_metadata
):
    """Save a sequence as one .npz file, atomically.

    Parameters
    ----------
    path : str or os.PathLike   destination, written as given (no ".npz" is appended)
    vertices : (frames, n, 3) float array   stored as float32
    faces : (m, 3) int array                stored as int32
    colors : (frames, n, 3) float array in [0, 1], optional   stored as float32
    names : list of str, optional   frame names (default frame_0000, frame_0001, ...)
    compress : bool   zlib-compress the arrays (smaller, slower)
    **arrays_and_metadata
        numpy arrays are stored as extra arrays under their keyword; anything else must be
        JSON-compatible and is stored in the metadata JSON.

    Returns
    -------
    path : str or os.PathLike   the `path` given
    """
    source = str(path)
    V = check_sequence_vertices(vertices, source)
    F = check_faces(faces, V.shape[1], source)
    colors = check_colors(colors, V.shape[1], source, leading=(len(V),))
    V32 = V.astype(np.float32)
    if not np.isfinite(V32).all():
        raise MeshValidationError(f"{source}: vertex coordinates overflow float32")
    if F.max() > np.iinfo(np.int32).max:
        raise MeshValidationError(f"{source}: face indices overflow int32")
    if names is None:
        names = [f"frame_{i:04d}" for i in range(len(V))]
    names = [str(name) for name in names]
    if len(names) != len(V):
        raise MeshValidationError(f"{source}: {len(names)} frame names for {len(V)} frames")

    arrays = {"vertices": V32, "faces": F.astype(np.int32)}
    if colors is not None:
        arrays["colors"] = colors
    metadata = {}
    for key, value in arrays_and_metadata.items():
        if key in _RESERVED:
            raise ValueError(f"{source}: {key!r} is a reserved name in a sequence npz")
        if isinstance(value, np.ndarray):
            if value.dtype.hasobject:
                raise ValueError(f"{source}: array {key!r} has dtype object, which needs pickle")
            arrays[key] = value
        else:
            metadata[key] = value.item() if isinstance(value, np.generic) else value
    document = {"format": FORMAT, "version": VERSION, "names": names, "metadata": metadata}
    try:
        text = json.dumps(document, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{source}: metadata is not JSON-compatible ({err})") from err
    arrays["metadata"] = np.array(text)

    with atomic_write(path) as file:
        savez_stable(file, arrays, compress=compress)
    return path


_EPOCH = (1980, 1, 1, 0, 0, 0)  # the earliest time a zip entry can carry


def savez_stable(file, arrays, *, compress=True):
    """``np.savez(_compressed)`` with nothing of the moment in it: numpy stamps every entry with
    the time it was written, so the same arrays saved twice differ; here every entry carries the
    same time, and the same arrays give the same bytes. ``np.load`` reads it as any npz.

    Parameters
    ----------
    file : path or binary file object
    arrays : dict name -> array_like    saved in this order, as ``name.npy``, never pickled
    """
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(file, mode="w", compression=method, allowZip64=True) as archive:
        for name, value in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with archive.open(info, mode="w", force_zip64=True) as entry:
                np.lib.format.write_array(entry, np.asanyarray(value), allow_pickle=False)


def load_sequence_npz(path):
    """Load a sequence saved by `save_sequence_npz`.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    sequence : MeshSequence
        vertices as float64, faces as int64, `metadata` and extra `arrays` as saved, `source`
        the path.

    Raises
    ------
    MeshFormatError
        Missing or unreadable file, not an npz, truncated, a required array missing or with the
        wrong shape or dtype, malformed metadata.
    MeshValidationError
        Non-finite coordinates or face indices out of range.
    """
    source = str(path)
    try:
        with open(path, "rb") as file:
            magic = file.read(6)
    except OSError as err:
        raise MeshFormatError(f"{source}: cannot read the file ({err.strerror})") from err
    if magic.startswith(b"\x93NUMPY"):
        raise MeshFormatError(f"{source}: is a single-array .npy file, not an .npz archive")
    if not magic.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        raise MeshFormatError(f"{source}: not an .npz file (no zip signature at the start)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            stored = {key: archive[key] for key in archive.files}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as err:
        raise MeshFormatError(f"{source}: truncated or corrupt .npz file ({err})") from err
    except ValueError as err:  # object arrays, malformed .npy headers
        raise MeshFormatError(f"{source}: unreadable array in the .npz file ({err})") from err

    for key in ("vertices", "faces"):
        if key not in stored:
            raise MeshFormatError(
                f"{source}: missing array {key!r} (has: {', '.join(sorted(stored)) or 'none'})"
            )
    V, F, colors = stored.pop("vertices"), stored.pop("faces"), stored.pop("colors", None)
    if V.dtype.kind != "f" or V.ndim != 3 or V.shape[2] != 3:
        raise MeshFormatError(
            f"{source}: 'vertices' must be a (frames, n, 3) float array, got {V.shape} {V.dtype}"
        )
    if F.dtype.kind not in "iu" or F.ndim != 2 or F.shape[1] != 3:
        raise MeshFormatError(
            f"{source}: 'faces' must be an (m, 3) integer array, got {F.shape} {F.dtype}"
        )
    if colors is not None and (colors.dtype.kind != "f" or colors.shape != V.shape):
        raise MeshFormatError(
            f"{source}: 'colors' must be a {V.shape} float array, got {colors.shape} "
            f"{colors.dtype}"
        )
    document = _read_metadata(stored.pop("metadata", None), source)
    return MeshSequence(
        V.astype(np.float64),
        F.astype(np.int64),
        document.get("names"),
        colors,
        source,
        metadata=document.get("metadata", {}),
        arrays=stored,
    )


def _read_metadata(array, source):
    if array is None:
        return {}
    if array.ndim != 0 or array.dtype.kind != "U":
        raise MeshFormatError(f"{source}: 'metadata' must be a single JSON string")
    try:
        document = json.loads(str(array))
    except json.JSONDecodeError as err:
        raise MeshFormatError(f"{source}: 'metadata' is not valid JSON ({err})") from err
    if not isinstance(document, dict) or document.get("format", FORMAT) != FORMAT:
        raise MeshFormatError(f"{source}: 'metadata' is not a {FORMAT} description")
    version = document.get("version", VERSION)
    if not isinstance(version, int) or version > VERSION:
        raise MeshFormatError(
            f"{source}: unsupported format version {version!r} (this reader knows {VERSION})"
        )
    names = document.get("names")
    if names is not None and (
        not isinstance(names, list) or not all(isinstance(name, str) for name in names)
    ):
        raise MeshFormatError(f"{source}: 'metadata' names must be a list of strings")
    return document

"""Exceptions raised by :mod:`engine.mesh_io`.

Every message starts with the file it is about (a path, or ``archive.zip:member.obj`` for a zip
member) and then names the problem, so the text can be shown to a user as is.
"""

from __future__ import annotations


class MeshError(ValueError):
    """Base class for every mesh reading, writing and validation error."""


class MeshFormatError(MeshError):
    """The file cannot be read: unsupported type, missing, unparseable or truncated."""


class MeshValidationError(MeshError):
    """The file parsed but the mesh is unusable: empty, non-finite, or face index out of range."""


class MeshSequenceError(MeshError):
    """The frames do not form a sequence: no mesh files, or topology differing between frames."""

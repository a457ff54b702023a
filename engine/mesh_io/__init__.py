"""Mesh file I/O: single meshes (OBJ, PLY, OFF, GLB) and sequences (directories, zips, npz).

Everything read is validated (see `Mesh`); every error is a `MeshError` whose message starts
with the file it is about. Readers return the file's coordinates unchanged; `units` converts
captures in centimetres or millimetres, or with +Z up, to metres with +Y up (and detects which).
docs/file-formats.md ("Mesh files and sequences") describes the accepted formats and rules.
"""

from .errors import MeshError, MeshFormatError, MeshSequenceError, MeshValidationError
from .frames import DEFAULT_MAX_MEMBER_BYTES, DEFAULT_MAX_TOTAL_BYTES, list_frames
from .mesh import Mesh, validate_mesh
from .mesh_file import MESH_EXTENSIONS, read_mesh, write_mesh
from .mesh_sequence import MeshSequence
from .natural_sort import natural_key
from .npz import load_sequence_npz, save_sequence_npz
from .obj import write_obj
from .off import write_off
from .ply import write_ply
from .sequence import read_frames, read_sequence, write_frames, write_sequence
from .triangulate import fan_triangulate
from .units import Convention, from_metres_y_up, resolve_convention, to_metres_y_up

__all__ = [
    "Convention",
    "DEFAULT_MAX_MEMBER_BYTES",
    "DEFAULT_MAX_TOTAL_BYTES",
    "MESH_EXTENSIONS",
    "Mesh",
    "MeshError",
    "MeshFormatError",
    "MeshSequence",
    "MeshSequenceError",
    "MeshValidationError",
    "fan_triangulate",
    "from_metres_y_up",
    "list_frames",
    "load_sequence_npz",
    "natural_key",
    "read_frames",
    "read_mesh",
    "read_sequence",
    "resolve_convention",
    "save_sequence_npz",
    "to_metres_y_up",
    "validate_mesh",
    "write_frames",
    "write_mesh",
    "write_obj",
    "write_off",
    "write_ply",
    "write_sequence",
]

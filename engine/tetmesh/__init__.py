"""Tetrahedral meshes: tetrahedralise a surface, embed the surface, operators G, D, L.

One function per file, each named after what it returns:

``V_tet, T = tetrahedralize(V, F)``            fill a (possibly open) surface: voxel lattice
``B = embed_barycentric(P, V_tet, T)``         surface points as tet-vertex combinations
``tet_index, W, distance = tet_barycentric(P, V_tet, T)``
``F, tet_index = boundary_faces(T)``           outward boundary triangles
``count, label = tet_components(T, k)``       connected parts (vertices joined through tets)
``volume = tet_volumes(V, T)``                 signed volumes
``G = tet_gradient(V, T)``                     (3t, k) gradient operator
``D = tet_mass(V, T)``                         (3t, 3t) volumes, each repeated 3 times
``L = tet_laplacian(V, T)``                    G^T D G
``F = deformation_gradients(V_rest, V_def, T)``  (t, 3, 3) (``rest_inverse``: its rest part, once)
``R, S = polar_decomposition(F)``              F = R S, det R = +1
``q = rotations_to_quaternions(R)``, ``R = quaternions_to_rotations(q)``

Casas et al. 2012, section 4.1 and eq. (2); DESIGN.md pipeline step 7.
"""

from .boundary_faces import boundary_faces
from .deformation_gradients import deformation_gradients, rest_inverse
from .embed_barycentric import embed_barycentric, tet_barycentric
from .polar_decomposition import polar_decomposition
from .quaternions import quaternions_to_rotations, rotations_to_quaternions
from .tet_components import tet_components
from .tet_gradient import tet_gradient
from .tet_laplacian import tet_laplacian
from .tet_mass import tet_mass
from .tet_volumes import tet_volumes
from .tetrahedralize import tetrahedralize

__all__ = [
    "boundary_faces",
    "deformation_gradients",
    "embed_barycentric",
    "polar_decomposition",
    "quaternions_to_rotations",
    "rest_inverse",
    "rotations_to_quaternions",
    "tet_barycentric",
    "tet_components",
    "tet_gradient",
    "tet_laplacian",
    "tet_mass",
    "tet_volumes",
    "tetrahedralize",
]

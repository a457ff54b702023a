"""Per-frame reconstruction as a multi-view studio delivers it.

Every frame is re-meshed on its own from the volume of the true surfaces (body and garments):
occupancy by winding numbers, a morphological closing that merges limbs wherever they come
within a couple of centimetres of each other or of the body (hands on hips, crossed arms, a
knee to the chest, legs together, a skirt on the thighs), interior cavities filled, marching
cubes, quadric decimation to the target vertex count. Vertices near a true surface are snapped
onto it (colours come from there); the ones that bridge a contact stay where the closing put
them. Then the defects of real reconstructions: holes that change from frame to frame (soles on
the ground, the top of the head, some contact bridges, random occlusions), a few small floating
fragments, and noise along the normals. The colours are the albedo as the studio's lights and
cameras show it in that frame (``lighting``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import fast_simplification
import numpy as np
import scipy.ndimage as ndimage
import scipy.sparse as sp
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes

from engine.surface import SurfaceQuery, enclosed_volume, vertex_normals
from engine.synthetic.studio.lighting import StudioLight, lit_colours
from engine.synthetic.studio.voxelize import grid_for, occupancy

FRAGMENT_COLOUR = np.array([0.45, 0.45, 0.42])


@dataclass(frozen=True)
class StudioCamera:
    """How a frame is reconstructed (lengths in metres).

    spacing : voxel size of the volumetric fusion
    merge : gaps narrower than about this are closed (limbs in contact merge)
    vertices : target vertex count after decimation
    noise : standard deviation of the displacement along the normals
    holes : mean number of random occlusion holes per frame
    fragments : mean number of floating fragments per frame
    light : the studio's light and exposure in the colours (``lighting.StudioLight``), or None
            for the bare albedo
    """

    spacing: float = 0.006
    merge: float = 0.02
    vertices: int = 10_000
    noise: float = 0.0025
    holes: float = 1.5
    fragments: float = 2.5
    light: StudioLight | None = StudioLight()


def _ball(radius):
    r = int(radius)
    g = np.arange(-r, r + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    return x * x + y * y + z * z <= radius * radius + 1e-9


def _components(F, count):
    """Connected component label of every vertex (through faces)."""
    A = sp.coo_matrix((np.ones(3 * len(F)), (F.ravel(), np.roll(F, 1, axis=1).ravel())), shape=(count, count))
    return sp.csgraph.connected_components(A, directed=False)[1]


def surface_volume(V, F, camera, thin=None):
    """Closed, merged surface of the occupied volume: marching cubes then decimation.

    ``thin`` (a face mask) marks thin shells (garments): their occupancy is dilated by a voxel
    so that the grid never misses them; the snap onto the true surface takes the offset back.
    """
    h = camera.spacing
    radius = max(1.0, 0.5 * camera.merge / h)
    origin, shape = grid_for(V, h, int(np.ceil(radius)) + 4)
    if thin is None or not np.any(thin):
        inside = occupancy(V, F, origin, h, shape)
    else:
        inside = occupancy(V, F[~thin], origin, h, shape)
        inside |= ndimage.binary_dilation(occupancy(V, F[thin], origin, h, shape), structure=_ball(1.0))
    inside = ndimage.binary_closing(inside, structure=_ball(radius))
    inside = ndimage.binary_fill_holes(inside)
    field = ndimage.gaussian_filter(inside.astype(np.float32), sigma=0.8)
    verts, faces, _, _ = marching_cubes(field, level=0.5, spacing=(h, h, h))
    verts = verts + origin
    faces = faces.astype(np.int64)
    if enclosed_volume(verts, faces) < 0:
        faces = faces[:, ::-1]
    label = _components(faces, len(verts))[faces[:, 0]]
    sizes = np.bincount(label)
    faces = faces[sizes[label] >= max(100, 0.002 * len(faces))]  # specks of the grid, not fragments
    Vd, Fd = fast_simplification.simplify(verts, faces, target_count=2 * camera.vertices, agg=6.0)
    Vd, Fd = np.asarray(Vd, dtype=np.float64), np.asarray(Fd, dtype=np.int64)
    used = np.unique(Fd)
    remap = np.full(len(Vd), -1)
    remap[used] = np.arange(len(used))
    return Vd[used], remap[Fd]


def contact_vertices(V_rest, V, *, radius=0.012, rest_gap=0.06):
    """Vertices in contact: within ``radius`` of a point that was farther than ``rest_gap`` at rest.

    Parameters
    ----------
    V_rest : (n, 3) float array   the template at rest (body and garments)
    V : (n, 3) float array        the same vertices in a frame

    Returns
    -------
    contact : (n,) bool array     e.g. a hand on a hip, crossed forearms, a knee on the chest,
                                  a sleeve on the torso, the legs together (what a studio merges)
    """
    pairs = cKDTree(V).query_pairs(radius, output_type="ndarray")
    contact = np.zeros(len(V), dtype=bool)
    if len(pairs):
        far = np.linalg.norm(V_rest[pairs[:, 0]] - V_rest[pairs[:, 1]], axis=1) > rest_gap
        contact[pairs[far].ravel()] = True
    return contact


@lru_cache(maxsize=4)
def _icosphere(subdivisions):
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)


def _fragment(rng, centre, size, subdivisions=1):
    """A small lumpy closed blob (an icosphere, scaled and dented)."""
    V, F = _icosphere(subdivisions)
    V = V * size * rng.uniform(0.5, 1.0, 3)
    V = V * (1.0 + 0.25 * rng.uniform(-1, 1, (len(V), 1)))
    return V + centre, F


def _face_frames(V, F):
    """Centroids and unit normals (m, 3) of a mesh's faces."""
    centroid = V[F].mean(axis=1)
    normal = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-15)
    return centroid, normal


def sole_faces(centroid, normal):
    """(m,) bool: faces on the ground facing down (soles, the underside of a fallen body): no
    camera sees them."""
    return (centroid[:, 1] < 0.02) & (normal[:, 1] < -0.3)


def head_top_faces(centroid, normal, head_top, head_up, radius):
    """(m,) bool: faces within ``radius`` of the top of the head and facing up from it (hair and
    the cameras' angles leave a hole there)."""
    up = head_up / np.linalg.norm(head_up)
    return (np.linalg.norm(centroid - head_top, axis=1) < radius) & (normal @ up > 0.2)


def occlusion_faces(rng, centroid, camera):
    """(m,) bool: random occlusions, ``camera.holes`` per frame on average, each the faces within
    2-5 cm of a random face."""
    drop = np.zeros(len(centroid), dtype=bool)
    for _ in range(rng.poisson(camera.holes)):
        centre = centroid[rng.integers(len(centroid))]
        drop |= np.linalg.norm(centroid - centre, axis=1) < rng.uniform(0.02, 0.05)
    return drop


def camera_holes(V, F, *, camera, seed, head_top, head_up):
    """Faces of a true surface that the studio's cameras would leave open (``reconstruct_frame``'s
    holes, on the surface itself: soles on the ground, a patch on top of the head, occlusions;
    there are no bridges over gaps on a true surface).

    Parameters
    ----------
    V : (n, 3) float array   metres, Y up
    F : (m, 3) int array
    camera : StudioCamera
    seed : int               the occlusions' and the head patch's randomness
    head_top, head_up : (3,) float arrays

    Returns
    -------
    drop : (m,) bool array
    """
    rng = np.random.default_rng(seed)
    centroid, normal = _face_frames(np.asarray(V, dtype=np.float64), np.asarray(F))
    drop = sole_faces(centroid, normal)
    drop |= head_top_faces(centroid, normal, head_top, head_up, rng.uniform(0.03, 0.07))
    return drop | occlusion_faces(rng, centroid, camera)


def reconstruct_frame(V, F, colors, *, camera, seed, thin=None, contact=None, head_top=None, head_up=None):
    """One frame as the studio reconstructs it.

    Parameters
    ----------
    V : (n, 3) float array       true surfaces of the frame (metres, Y up), every component closed
    F : (m, 3) int array
    colors : (n, 3) float array  albedo carried onto the reconstruction
    camera : StudioCamera
    seed : int                   the frame's own randomness (holes, fragments, noise)
    thin : (m,) bool array or None   faces of thin shells (garments)
    contact : (n,) bool array or None  true vertices in contact (``contact_vertices``), counted
                                 in the statistics
    head_top, head_up : (3,) float arrays or None   top of the head and its up direction (for
                                 the hole the cameras leave there)

    Returns
    -------
    V_new : (k, 3) float array, F_new : (l, 3) int array, colors_new : (k, 3) float array
    stats : dict   vertices, boundary_edges, holes (boundary loops), components, fragments,
                   bridged (vertices on bridges over gaps), merged (vertices where touching
                   surfaces merged, bridges included), noise_m
    """
    rng = np.random.default_rng(seed)
    h = camera.spacing
    Vr, Fr = surface_volume(V, F, camera, thin)
    points, faces, bary, distance = SurfaceQuery(V, F, k=4).closest(Vr)  # Vr is near V: 4 suffice
    snap = np.clip((2.0 * h - distance) / h, 0.0, 1.0)[:, None]
    Vr = Vr + snap * (points - Vr)
    C = np.einsum("qk,qkc->qc", bary, np.asarray(colors)[F[faces]])
    N = np.einsum("qk,qkc->qc", bary, vertex_normals(V, F)[F[faces]])   # the true surface's, lit
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
    bridged = distance > 1.5 * h
    merged = bridged | (np.asarray(contact)[F[faces]].any(axis=1) if contact is not None else False)
    centroid, normal = _face_frames(Vr, Fr)
    drop = sole_faces(centroid, normal)
    if head_top is not None:
        drop |= head_top_faces(centroid, normal, head_top, head_up, rng.uniform(0.03, 0.07))
    if np.any(bridged):  # contact bridges: some are missing in the reconstruction
        on_bridge = bridged[Fr].all(axis=1)
        if np.any(on_bridge):
            label = _components(Fr[on_bridge], len(Vr))[Fr[on_bridge, 0]]
            gone = rng.uniform(size=label.max() + 1) < 0.5
            drop[np.flatnonzero(on_bridge)[gone[label]]] = True
    drop |= occlusion_faces(rng, centroid, camera)
    Fr = Fr[~drop]
    used = np.unique(Fr)
    remap = np.full(len(Vr), -1)
    remap[used] = np.arange(len(used))
    Vr, Fr, C, N, bridged, merged = Vr[used], remap[Fr], C[used], N[used], bridged[used], merged[used]
    Vr = Vr + rng.normal(0.0, camera.noise, (len(Vr), 1)) * vertex_normals(Vr, Fr)
    lo, hi = V.min(axis=0), V.max(axis=0)
    parts_V, parts_F, parts_C, parts_N = [Vr], [Fr], [C], [N]
    count = len(Vr)
    fragments = rng.poisson(camera.fragments)
    for _ in range(fragments):
        centre = rng.uniform(lo - 0.25, hi + 0.25)
        centre[1] = rng.uniform(0.01, 0.05) if rng.uniform() < 0.4 else rng.uniform(0.1, hi[1] + 0.2)
        Vf, Ff = _fragment(rng, centre, rng.uniform(0.008, 0.03), subdivisions=int(rng.integers(0, 2)))
        Vf = Vf + rng.normal(0.0, camera.noise, Vf.shape)
        parts_V.append(Vf)
        parts_F.append(Ff + count)
        parts_C.append(np.tile(FRAGMENT_COLOUR, (len(Vf), 1)))
        parts_N.append(vertex_normals(Vf, Ff))
        count += len(Vf)
    V_new, F_new, C_new = np.concatenate(parts_V), np.concatenate(parts_F), np.concatenate(parts_C)
    if camera.light is not None:   # drawn last: the geometry is the same with or without light
        C_new = lit_colours(C_new, np.concatenate(parts_N), rng, camera.light)
    stats = frame_statistics(F_new, len(V_new))
    stats.update(fragments=int(fragments), bridged=int(bridged.sum()), merged=int(merged.sum()),
                 noise_m=camera.noise)
    return V_new, F_new, np.clip(C_new, 0.0, 1.0), stats


def frame_statistics(F, count):
    """Vertices, boundary edges, boundary loops (holes) and connected components of a mesh."""
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    boundary = unique[counts == 1]
    loops = 0
    if len(boundary):
        A = sp.coo_matrix((np.ones(len(boundary)), (boundary[:, 0], boundary[:, 1])), shape=(count, count))
        labels = sp.csgraph.connected_components(A, directed=False)[1]
        loops = len(np.unique(labels[np.unique(boundary)]))
    return {"vertices": int(count), "boundary_edges": int(len(boundary)), "holes": int(loops),
            "components": int(len(np.unique(_components(F, count)[np.unique(F)])))}

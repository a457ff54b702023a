"""A procedural humanoid: a watertight body surface with skeleton, skin weights and regions.

The body is the zero level set of a smooth union of round cones and ellipsoids attached to the
skeleton's segments, meshed by marching cubes and decimated with quadric error metrics to the
requested vertex count. Skin weights start as the segment that owns each surface point and are
diffused over the surface (heat method with the cotangent Laplacian), so joints bend smoothly.
"""

from __future__ import annotations

from dataclasses import dataclass

import fast_simplification
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from skimage.measure import marching_cubes

from engine.surface import cotangent_laplacian, enclosed_volume, lumped_mass, model_size
from engine.synthetic.skeleton import ARM_DROP, HAND, JOINT_INDEX, JOINTS, Skeleton

MIN_VERTICES, MAX_VERTICES = 1_000, 50_000
INFLUENCES = 4  # skin weights kept per vertex
BLEND_RADIUS = 0.02  # smooth-union radius (m) of the body primitives


def _sd_round_cone(p, a, b, r1, r2):
    """Exact signed distance to a round cone (capsule with radii r1 at a, r2 at b)."""
    ba = b - a
    l2 = ba @ ba
    rr = r1 - r2
    a2 = l2 - rr * rr
    il2 = 1.0 / l2
    pa = p - a
    y = pa @ ba
    z = y - l2
    x2 = np.sum((pa * l2 - y[:, None] * ba) ** 2, axis=1)
    y2, z2 = y * y * l2, z * z * l2
    k = np.sign(rr) * rr * rr * x2
    side = (np.sqrt(x2 * a2 * il2) + y * rr) * il2 - r1
    d = np.where(np.sign(y) * a2 * y2 < k, np.sqrt(x2 + y2) * il2 - r1, side)
    return np.where(np.sign(z) * a2 * z2 > k, np.sqrt(x2 + z2) * il2 - r2, d)


def _sd_ellipsoid(p, centre, radii):
    """Signed distance bound to an axis-aligned ellipsoid (exact on the surface)."""
    q = p - centre
    k0 = np.linalg.norm(q / radii, axis=1)
    k1 = np.linalg.norm(q / (radii * radii), axis=1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


@dataclass(frozen=True)
class _Primitive:
    joint: str
    kind: str  # "cone" or "ellipsoid"
    a: np.ndarray  # cone start or ellipsoid centre
    b: np.ndarray  # cone end or ellipsoid radii
    r1: float = 0.0
    r2: float = 0.0
    blend: float = BLEND_RADIUS  # smooth-union radius with what came before (reference body, m)

    def distance(self, p):
        if self.kind == "cone":
            return _sd_round_cone(p, self.a, self.b, self.r1, self.r2)
        return _sd_ellipsoid(p, self.a, self.b)

    def bounds(self, margin):
        if self.kind == "cone":
            r = max(self.r1, self.r2)
            lo, hi = np.minimum(self.a, self.b) - r, np.maximum(self.a, self.b) + r
        else:
            lo, hi = self.a - self.b, self.a + self.b
        return lo - margin, hi + margin


def _primitives(skeleton):
    """Round cones and ellipsoids of the body, each owned by the joint that moves it."""
    s = skeleton.scale
    P = skeleton.position
    v = lambda *xyz: np.array(xyz, dtype=float) * s  # noqa: E731
    prims = [
        _Primitive("pelvis", "ellipsoid", v(0, 0.945, -0.005), v(0.165, 0.12, 0.115)),
        _Primitive("spine", "ellipsoid", v(0, 1.10, 0.0), v(0.15, 0.14, 0.105), blend=0.08),
        _Primitive("chest", "ellipsoid", v(0, 1.28, -0.005), v(0.17, 0.15, 0.11), blend=0.08),
        _Primitive("chest", "cone", v(0.17, 1.415, -0.02), v(-0.17, 1.415, -0.02), 0.058 * s, 0.058 * s,
                   blend=0.05),
        _Primitive("neck", "cone", v(0, 1.40, -0.02), v(0, 1.585, -0.01), 0.056 * s, 0.05 * s, blend=0.03),
        _Primitive("head", "ellipsoid", v(0, 1.645, 0.01), v(0.08, 0.105, 0.095), blend=0.03),
        _Primitive("head", "ellipsoid", v(0, 1.585, 0.035), v(0.06, 0.05, 0.065), blend=0.03),
        _Primitive("head", "ellipsoid", v(0, 1.635, 0.10), v(0.014, 0.022, 0.02), blend=0.01),
    ]
    for side, sign in (("l", 1.0), ("r", -1.0)):
        arm = np.array([sign * np.cos(ARM_DROP), -np.sin(ARM_DROP), 0.0])
        shoulder, elbow, wrist = P(f"shoulder_{side}"), P(f"elbow_{side}"), P(f"wrist_{side}")
        hip, knee, ankle = P(f"hip_{side}"), P(f"knee_{side}"), P(f"ankle_{side}")
        x = hip[0] / s
        prims += [
            _Primitive(f"shoulder_{side}", "cone", shoulder, elbow, 0.052 * s, 0.04 * s),
            _Primitive(f"elbow_{side}", "cone", elbow, wrist, 0.04 * s, 0.029 * s),
            _Primitive(f"wrist_{side}", "cone", wrist + 0.02 * s * arm, wrist + 0.75 * HAND * s * arm,
                       0.032 * s, 0.027 * s),
            _Primitive(f"hip_{side}", "cone", hip, knee, 0.082 * s, 0.052 * s),
            _Primitive(f"knee_{side}", "cone", knee, ankle, 0.05 * s, 0.034 * s),
            _Primitive(f"knee_{side}", "ellipsoid", knee + 0.3 * (ankle - knee) + v(0, 0, -0.018),
                       v(0.046, 0.11, 0.05)),
            _Primitive(f"ankle_{side}", "cone", ankle, v(x, 0.045, 0.02), 0.035 * s, 0.04 * s),
            _Primitive(f"ankle_{side}", "cone", v(x, 0.04, -0.055), v(x, 0.028, 0.15), 0.04 * s, 0.028 * s),
        ]
    return prims


def _smooth_min(a, b, k):
    """Polynomial smooth minimum: equals min(a, b) where |a - b| >= k."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def _body_field(prims, origin, spacing, shape, scale):
    """Sample the smooth-union distance on a grid; each primitive only touches its box."""
    far = 1.0
    field = np.full(shape, far, dtype=np.float64)
    axes = [origin[i] + spacing * np.arange(shape[i]) for i in range(3)]
    for prim in prims:
        blend = prim.blend * scale
        lo, hi = prim.bounds(3 * spacing + blend)
        idx = [slice(max(int(np.floor((lo[i] - origin[i]) / spacing)), 0),
                     min(int(np.ceil((hi[i] - origin[i]) / spacing)) + 1, shape[i])) for i in range(3)]
        gx, gy, gz = np.meshgrid(axes[0][idx[0]], axes[1][idx[1]], axes[2][idx[2]], indexing="ij")
        pts = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
        d = prim.distance(pts).reshape(gx.shape)
        field[tuple(idx)] = _smooth_min(field[tuple(idx)], d, blend)
    return field


def _mesh_body(prims, scale, target_vertices):
    """Marching cubes of the body field at a resolution suited to the target, then decimation."""
    # Marching cubes gives about 1.7 vertices per h^2 of surface (about 2.1 m^2 at 1.75 m):
    # aim at 4x the target before quadric decimation, never finer than 2.5 mm.
    area = 2.1 * scale**2
    spacing = max(np.sqrt(1.7 * area / (4.0 * target_vertices)), 0.0025 * scale)
    lo = np.array([-0.8, -0.02, -0.25]) * scale - 2 * spacing
    hi = np.array([0.8, 1.8, 0.3]) * scale + 2 * spacing
    shape = tuple(int(np.ceil((hi[i] - lo[i]) / spacing)) + 1 for i in range(3))
    field = _body_field(prims, lo, spacing, shape, scale)
    verts, faces, _, _ = marching_cubes(field, level=0.0, spacing=(spacing,) * 3)
    verts = verts + lo
    faces = faces.astype(np.int64)
    if enclosed_volume(verts, faces) < 0:
        faces = faces[:, ::-1]
    target_faces = 2 * target_vertices - 4  # closed genus-0 surface: F = 2V - 4
    V, F = fast_simplification.simplify(verts, faces, target_count=target_faces, agg=5.0)
    return _largest_component(np.asarray(V, dtype=float), np.asarray(F, dtype=np.int64))


def _largest_component(V, F):
    """Keep the largest face-connected component and drop unreferenced vertices."""
    n = len(V)
    A = sp.coo_matrix((np.ones(len(F) * 3), (F[:, [0, 1, 2]].ravel(), F[:, [1, 2, 0]].ravel())),
                      shape=(n, n))
    count, labels = sp.csgraph.connected_components(A, directed=False)
    if count > 1:
        used = np.bincount(labels[F[:, 0]], minlength=count)
        F = F[labels[F[:, 0]] == np.argmax(used)]
    keep = np.unique(F)
    remap = np.full(n, -1, dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    return V[keep], remap[F]


def _skin_weights(V, F, prims, scale):
    """Diffused segment ownership -> (n, INFLUENCES) joint indices and weights."""
    owner = np.argmin(np.stack([p.distance(V) for p in prims], axis=1), axis=1)
    joint_of_prim = np.array([JOINT_INDEX[p.joint] for p in prims])
    W0 = np.zeros((len(V), len(JOINTS)))
    W0[np.arange(len(V)), joint_of_prim[owner]] = 1.0
    L, M = cotangent_laplacian(V, F), lumped_mass(V, F)
    t = (0.03 * scale) ** 2
    W = spla.splu((M + t * L).tocsc()).solve(M @ W0)
    W = np.clip(W, 0.0, None)
    index = np.argsort(-W, axis=1)[:, :INFLUENCES]
    weight = np.take_along_axis(W, index, axis=1)
    weight /= weight.sum(axis=1, keepdims=True)
    return index.astype(np.int64), weight, joint_of_prim[owner]


def _smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


@dataclass(frozen=True)
class Body:
    """A riggable humanoid: rest surface, skeleton and per-vertex attributes.

    Attributes
    ----------
    V : (n, 3) float array            rest (A-pose) vertices, metres, Y up, facing +Z
    F : (m, 3) int array              outward-oriented triangles of a closed surface
    skeleton : Skeleton
    weight_index : (n, 4) int array   joints influencing each vertex
    weight : (n, 4) float array       their skin weights (rows sum to 1)
    segment : (n,) int array          the joint owning each vertex (before diffusion)
    soft_tissue : (n,) float array    0..1 amplitude of soft-tissue jiggle
    garment : (n,) float array        0..1 amplitude of the loose shirt's lag
    colors : (n, 3) float array       albedo in [0, 1] (skin, striped shirt, trousers, shoes)
    """

    V: np.ndarray
    F: np.ndarray
    skeleton: Skeleton
    weight_index: np.ndarray
    weight: np.ndarray
    segment: np.ndarray
    soft_tissue: np.ndarray
    garment: np.ndarray
    colors: np.ndarray

    @property
    def size(self):
        """Model size: largest extent of the rest bounding box."""
        return model_size(self.V)

    def hand_vertices(self, side):
        """Indices of the vertices owned by the wrist of ``side`` ('l' or 'r')."""
        return np.flatnonzero(self.segment == JOINT_INDEX[f"wrist_{side}"])

    def joint_weight(self, name):
        """(n,) skin weight of joint ``name`` at every vertex."""
        j = JOINT_INDEX[name]
        return np.sum(np.where(self.weight_index == j, self.weight, 0.0), axis=1)


def build_body(n_vertices=3000, height=1.75):
    """Build the procedural humanoid.

    Parameters
    ----------
    n_vertices : int     approximate vertex count, 1,000 to 50,000
    height : float       standing height in metres

    Returns
    -------
    body : Body

    Notes
    -----
    Deterministic: the same arguments always give the same mesh.
    """
    if not MIN_VERTICES <= n_vertices <= MAX_VERTICES:
        raise ValueError(f"n_vertices must be between {MIN_VERTICES} and {MAX_VERTICES}, got {n_vertices}")
    if not 1.0 <= height <= 2.5:
        raise ValueError(f"height must be between 1.0 and 2.5 m, got {height}")
    skeleton = Skeleton.humanoid(height)
    prims = _primitives(skeleton)
    V, F = _mesh_body(prims, skeleton.scale, int(n_vertices))
    weight_index, weight, segment = _skin_weights(V, F, prims, skeleton.scale)

    def w(*names):
        return sum(np.sum(np.where(weight_index == JOINT_INDEX[n], weight, 0.0), axis=1) for n in names)

    y = V[:, 1] / skeleton.scale
    torso = w("pelvis", "spine", "chest")
    soft = np.clip(w("spine") + 0.7 * w("pelvis") + 0.6 * w("hip_l", "hip_r")
                   + 0.5 * w("shoulder_l", "shoulder_r") + 0.35 * w("chest"), 0.0, 1.0)
    garment = np.clip(torso * _smoothstep(1.25, 0.95, y) * _smoothstep(0.84, 0.90, y), 0.0, 1.0)

    skin = np.array([0.86, 0.68, 0.56])
    shirt_a, shirt_b = np.array([0.80, 0.22, 0.18]), np.array([0.95, 0.93, 0.88])
    trousers, shoes = np.array([0.16, 0.22, 0.42]), np.array([0.12, 0.10, 0.09])
    stripes = 0.5 + 0.5 * np.sign(np.sin(2 * np.pi * y / 0.06))
    shirt = shirt_a * stripes[:, None] + shirt_b * (1 - stripes[:, None])
    part = {
        "skin": w("head", "neck", "elbow_l", "elbow_r", "wrist_l", "wrist_r"),
        "shirt": w("chest", "spine", "shoulder_l", "shoulder_r") + w("pelvis") * _smoothstep(0.86, 0.92, y),
        "trousers": w("hip_l", "hip_r", "knee_l", "knee_r") + w("pelvis") * (1 - _smoothstep(0.86, 0.92, y)),
        "shoes": w("ankle_l", "ankle_r"),
    }
    colors = (part["skin"][:, None] * skin + part["shirt"][:, None] * shirt
              + part["trousers"][:, None] * trousers + part["shoes"][:, None] * shoes)
    colors = np.clip(colors / sum(part.values())[:, None], 0.0, 1.0)
    return Body(V=V, F=F, skeleton=skeleton, weight_index=weight_index, weight=weight,
                segment=segment, soft_tissue=soft, garment=garment, colors=colors)

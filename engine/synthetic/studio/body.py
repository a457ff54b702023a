"""The studio performer: the MakeHuman body (CC0), its skeleton and skin weights, dressed in a
flared skirt and wide sleeves.

The template is the body (a closed genus-0 surface) followed by three closed garment shells
(skirt, left sleeve, right sleeve): every component is watertight and outward oriented, so
volumes, centres of mass and inside tests work on the template and on every consistent frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import fast_simplification
import numpy as np
from scipy.spatial import cKDTree

from engine.surface import model_size
from engine.synthetic.studio import garment as garments
from engine.synthetic.studio.assets import makehuman_body

PARTS = ("body", "skirt", "sleeve_l", "sleeve_r")
FULL_VERTICES = 13_380


@dataclass(frozen=True, eq=False)  # hashed by identity (cached calibrations)
class StudioSkeleton:
    """Joint names, parent indices and rest bone ends (metres, Y up, facing +Z, left = +X).

    Each joint drives the bone from its head to its tail (the thigh joint drives the thigh).
    """

    names: tuple
    parents: np.ndarray
    rest: np.ndarray  # (J, 3) bone heads: the joint positions
    tails: np.ndarray  # (J, 3)

    def index(self, name):
        return self.names.index(name)

    def position(self, name):
        return self.rest[self.index(name)]

    def to_dict(self):
        return {"joints": list(self.names), "parents": [int(p) for p in self.parents],
                "rest_positions": np.round(self.rest, 6).tolist(),
                "up": "+Y", "forward": "+Z", "left": "+X", "units": "m",
                "rig": "MakeHuman game_engine (fingers folded into the hands)"}


@dataclass(frozen=True)
class StudioBody:
    """Body and garments as one template (the attributes ``write_capture_template`` stores).

    Attributes
    ----------
    V : (n, 3) float array      rest vertices: body first, then skirt, sleeve_l, sleeve_r
    F : (m, 3) int array        outward-oriented triangles; every component closed
    skeleton : StudioSkeleton
    weight_index, weight : (n, 4) arrays   skin weights (rows sum to 1)
    segment : (n,) int array    the joint with the largest weight
    soft_tissue : (n,) float    0..1 soft-tissue amplitude (body only)
    garment : (n,) float        0..1 garment lag amplitude (garments only)
    colors : (n, 3) float       albedo in [0, 1]
    part : (n,) int             index into PARTS
    capsules : tuple of (head joint, tail joint, head radius, tail radius)   the legs, which
                                push the skirt aside
    clearance : (n,) float      how far a skirt vertex stays outside the leg capsules (its
                                sheet's offset); 0 elsewhere
    """

    V: np.ndarray
    F: np.ndarray
    skeleton: StudioSkeleton
    weight_index: np.ndarray
    weight: np.ndarray
    segment: np.ndarray
    soft_tissue: np.ndarray
    garment: np.ndarray
    colors: np.ndarray
    part: np.ndarray
    capsules: tuple = ()
    clearance: np.ndarray | None = None

    @property
    def size(self):
        return model_size(self.V)

    def hand_vertices(self, side):
        """Body vertices owned by the hand of ``side`` ('l' or 'r')."""
        return np.flatnonzero((self.segment == self.skeleton.index(f"hand_{side}")) & (self.part == 0))

    def joint_weight(self, names):
        """(n,) summed skin weight of the joints ``names`` at every vertex."""
        index = [self.skeleton.index(n) for n in names]
        return np.sum(np.where(np.isin(self.weight_index, index), self.weight, 0.0), axis=1)

    def part_faces(self, name):
        """Faces of one part (indices into V)."""
        k = PARTS.index(name)
        return self.F[self.part[self.F[:, 0]] == k]


def _decimate(V, F, weight_index, weight, target):
    """The body at ``target`` vertices (closed), weights carried from the nearest full vertex."""
    for agg in (3.0, 5.0, 7.0, 2.0):
        Vd, Fd = fast_simplification.simplify(V, F, target_count=2 * target - 4, agg=agg)
        Vd, Fd = np.asarray(Vd, dtype=float), np.asarray(Fd, dtype=np.int64)
        directed = np.concatenate([Fd[:, [0, 1]], Fd[:, [1, 2]], Fd[:, [2, 0]]])
        _, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
        if np.all(counts == 2) and len(np.unique(directed, axis=0)) == len(directed) \
                and len(np.unique(Fd)) == len(Vd):
            break
    else:
        raise RuntimeError(f"could not decimate the body to {target} vertices as a closed surface")
    nearest = cKDTree(V).query(Vd)[1]
    return Vd, Fd, weight_index[nearest], weight[nearest]


def _smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


@lru_cache(maxsize=2)
def build_studio_body(vertices=FULL_VERTICES, garment_detail=1.0):
    """The dressed studio performer.

    Parameters
    ----------
    vertices : int          body vertex count: 13,380 (the full MakeHuman body) or fewer
                            (quadric decimation, 1,000 at least)
    garment_detail : float  scales the garment grids (1: 64 sectors around the skirt)

    Returns
    -------
    body : StudioBody   deterministic for given arguments (cached)
    """
    data = makehuman_body()
    if not 1_000 <= vertices <= FULL_VERTICES:
        raise ValueError(f"studio body vertices must be between 1000 and {FULL_VERTICES}, got {vertices}")
    V = data["vertices"].astype(float)
    F = data["faces"].astype(np.int64)
    weight_index = data["weight_index"].astype(np.int64)
    weight = data["weight"].astype(float)
    if vertices < FULL_VERTICES:
        V, F, weight_index, weight = _decimate(V, F, weight_index, weight, int(vertices))
    names = tuple(str(n) for n in data["joint_names"])
    skeleton = StudioSkeleton(names=names, parents=data["joint_parents"].astype(np.int64),
                              rest=data["joint_head"].astype(float), tails=data["joint_tail"].astype(float))

    def weights_of(joints):
        index = [names.index(n) for n in joints]
        return np.sum(np.where(np.isin(weight_index, index), weight, 0.0), axis=1)

    rings = max(8, int(round(18 * garment_detail)))
    sectors = max(16, int(round(64 * garment_detail)))
    parts = [(V, F, weight_index, weight, np.zeros(len(V)), np.zeros(len(V)), np.zeros(len(V))),
             _skirt_part(V, weights_of, skeleton, rings, sectors)]
    parts += [_sleeve_part(V, weights_of, skeleton, side, max(6, rings // 2), max(12, sectors // 2))
              for side in ("l", "r")]
    # parts: (V, F, weight_index, weight, lag amplitude, u, s), body first
    offsets = np.cumsum([0] + [len(p[0]) for p in parts])[:-1]
    V_all = np.concatenate([p[0] for p in parts])
    F_all = np.concatenate([p[1] + offset for p, offset in zip(parts, offsets)])
    weight_index = np.concatenate([p[2] for p in parts])
    weight = np.concatenate([p[3] for p in parts])
    lag = np.concatenate([p[4] for p in parts])
    params = [(p[5], p[6]) for p in parts]
    part = np.concatenate([np.full(len(p[0]), k) for k, p in enumerate(parts)])
    segment = weight_index[np.arange(len(V_all)), np.argmax(weight, axis=1)]

    def w(*joints):
        index = [names.index(n) for n in joints]
        return np.sum(np.where(np.isin(weight_index, index), weight, 0.0), axis=1)

    soft = np.clip(0.8 * w("pelvis", "spine_01") + 0.6 * w("thigh_l", "thigh_r") + 0.5 * w("spine_02", "spine_03")
                   + 0.4 * w("upperarm_l", "upperarm_r"), 0.0, 1.0) * (part == 0)
    colors = _colors(V_all, w, params)
    legs = [(f"{bone}_{side}", f"{tail}_{side}") for side in "lr" for bone, tail in (("thigh", "calf"), ("calf", "foot"))]
    capsules = garments.limb_capsules(V_all, lambda bone: w(bone) * (part == 0), skeleton, legs)
    clearance = np.zeros(len(V_all))
    skirt = np.flatnonzero(part == 1)
    outer = np.arange(len(skirt)) < len(skirt) // 2  # the outer sheet comes first
    clearance[skirt] = np.where(outer, 0.006 + garments.THICKNESS, 0.006)
    return StudioBody(V=V_all, F=F_all, skeleton=skeleton, weight_index=weight_index,
                      weight=weight, segment=segment, soft_tissue=soft, garment=lag,
                      colors=colors, part=part, capsules=capsules, clearance=clearance)


def _skirt_part(V, weights_of, skeleton, rings, sectors):
    """The skirt, waist to just above the knees; its hem follows the thighs three quarters."""
    names = skeleton.names
    top = skeleton.position("spine_01")[1] + 0.02
    Vs, Fs, u, s = garments.skirt(V, weights_of, top=top, hem=skeleton.position("calf_l")[1] - 0.02,
                                  rings=rings, sectors=sectors)
    left = np.sin(2 * np.pi * u)  # +1 on the left (+X)
    hem = s ** 1.2
    W = np.zeros((len(Vs), len(names)))
    W[:, names.index("pelvis")] = 1.0 - 0.75 * hem - 0.3 * (1 - s) ** 4
    W[:, names.index("spine_01")] = 0.3 * (1 - s) ** 4
    W[:, names.index("thigh_l")] = 0.75 * hem * np.clip(0.5 + 0.5 * left, 0, 1)
    W[:, names.index("thigh_r")] = 0.75 * hem * np.clip(0.5 - 0.5 * left, 0, 1)
    return _garment_part(Vs, Fs, W, s ** 1.5, u, s)


def _sleeve_part(V, weights_of, skeleton, side, rings, sectors):
    """A bell sleeve on one forearm; its top follows the upper arm half way."""
    names = skeleton.names
    elbow, wrist = skeleton.position(f"lowerarm_{side}"), skeleton.position(f"hand_{side}")
    Vg, Fg, u, s = garments.sleeve(V, weights_of, elbow, wrist, rings=rings, sectors=sectors)
    W = np.zeros((len(Vg), len(names)))
    near = np.clip(1.0 - s / 0.15, 0.0, 1.0)
    W[:, names.index(f"upperarm_{side}")] = 0.5 * near
    W[:, names.index(f"lowerarm_{side}")] = 1.0 - 0.5 * near
    return _garment_part(Vg, Fg, W, s ** 2, u, s)


def _garment_part(V, F, W, amplitude, u, s):
    index = np.argsort(-W, axis=1, kind="stable")[:, :4]
    weight = np.take_along_axis(W, index, axis=1)
    weight = np.clip(weight, 0.0, None)
    weight /= weight.sum(axis=1, keepdims=True)
    return V, F, index, weight, amplitude, u, s


def _colors(V, w, params):
    """Skin, a striped top, dark leggings, shoes; a checked skirt and banded sleeves."""
    skin = np.array([0.86, 0.68, 0.56])
    top_a, top_b = np.array([0.20, 0.55, 0.60]), np.array([0.90, 0.90, 0.82])
    leggings, shoes = np.array([0.15, 0.15, 0.22]), np.array([0.35, 0.20, 0.12])
    y = V[:, 1]
    stripes = (0.5 + 0.5 * np.sign(np.sin(2 * np.pi * y / 0.05)))[:, None]
    top = top_a * stripes + top_b * (1 - stripes)
    amount = {
        "skin": w("head", "neck_01", "lowerarm_l", "lowerarm_r", "hand_l", "hand_r"),
        "top": w("spine_01", "spine_02", "spine_03", "clavicle_l", "clavicle_r", "upperarm_l", "upperarm_r",
                 "pelvis") * _smoothstep(0.90, 0.96, y),
        "leggings": w("thigh_l", "thigh_r", "calf_l", "calf_r") + w("pelvis") * (1 - _smoothstep(0.90, 0.96, y)),
        "shoes": w("foot_l", "foot_r", "ball_l", "ball_r"),
    }
    colors = (amount["skin"][:, None] * skin + amount["top"][:, None] * top
              + amount["leggings"][:, None] * leggings + amount["shoes"][:, None] * shoes)
    colors /= np.maximum(sum(amount.values()), 1e-9)[:, None]
    offset = 0
    for k, (u, s) in enumerate(params):
        n = len(u)
        if k == 1:  # skirt: red and cream checks
            check = ((np.floor(u * 24) + np.floor(s * 8)) % 2)[:, None]
            colors[offset:offset + n] = check * np.array([0.75, 0.15, 0.18]) + (1 - check) * np.array([0.95, 0.9, 0.8])
        elif k > 1:  # sleeves: the top's colour with a dark band at the cuff
            band = (s > 0.85)[:, None]
            colors[offset:offset + n] = band * np.array([0.1, 0.1, 0.12]) + (1 - band) * top_a
        offset += n
    return np.clip(colors, 0.0, 1.0)

"""The legs of a mesh without a skeleton: joints estimated from rings of the leg's own vertices,
and a two-bone inverse kinematics that moves a foot sideways on the ground while the thigh and
the shin keep their lengths (``LegRig``).

A held foot (``engine.graph.feet``) sits some centimetres from where the motion puts it. Moving
only the vertices below the knee shears the shin (a 20 cm offset over the 45 cm from ankle to
knee tilts it by 24 degrees and stretches it by 10%); here the whole leg carries it: the thigh
turns about the hip, the knee flexes or opens so that the ankle reaches its new place at the
same height, the shin turns to meet it, and the foot is moved as a whole (it stays flat and on
the ground). The joints are the centroids of bands of the body's vertices on the leg's side at
ankle, knee and hip heights on the rest mesh (the hip's: the pelvis just above the crotch, which
the legs do not move), taken from the frame being deformed, so they follow the motion; the
segments blend into each other over a band around each joint, and the thigh fades out below the
crotch.

A straight leg reaches nowhere sideways without lengthening: thigh and shin may lengthen along
their bones by up to ``stretch`` (3%). A place still out of reach, or farther than ``cap`` x the
leg's length from where the motion puts the foot, is not reached: the offset is shortened to the
reachable part along its direction (``LegRig.deform`` says by how much), and the foot slides by
the rest.
"""

from __future__ import annotations

import math

import numpy as np

from engine.graph.compiled import move_legs, ring_means

# heights as fractions of the rest mesh's height above its lowest point (a standing human body)
BANDS = {"ankle": (0.04, 0.08), "knee": (0.26, 0.31), "hip": (0.46, 0.50)}  # hip: the pelvis, one side
FOOT_TOP, SHIN_BOTTOM = 0.03, 0.13       # foot -> shin blend
SHIN_TOP, THIGH_BOTTOM = 0.21, 0.35      # shin -> thigh blend (the knee)
THIGH_TOP, HIP_TOP = 0.36, 0.44          # thigh -> the rest of the body (below the crotch)


def _ramp(y, lo, hi):
    """Smooth step from 0 at ``lo`` to 1 at ``hi``."""
    u = np.clip((y - lo) / (hi - lo), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _norm(v):
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


class LegRig:
    """Each leg's vertices, joint rings and segment weights on the rest mesh.

    Parameters
    ----------
    rest : (n, 3) float array         the rest mesh (standing, +Y up, +X the character's left)
    feet : list of (f,) int arrays    each foot's vertices: a leg is the side of the body its foot is on
    cap : float                       the largest offset, as a fraction of the leg's length (hip to
                                      ankle on the rest mesh), a foot is held at
    stretch : float                   how much longer (a fraction) thigh and shin may become to reach
                                      (a straight leg reaches nowhere sideways without it: 3%, 2.5 cm
                                      on the demo body, reaches 20 cm)
    """

    def __init__(self, rest, feet, *, cap=0.2, stretch=0.03):
        rest = np.array(rest, dtype=np.float64)  # (a writable copy: one compiled signature for every rest mesh)
        low = rest[:, 1].min()
        height = rest[:, 1].max() - low
        y = (rest[:, 1] - low) / height
        self.cap, self.stretch = float(cap), float(stretch)
        self.legs = []
        for foot in feet:
            side = np.sign(rest[foot, 0].mean())
            on_side = np.sign(rest[:, 0]) == side
            index = np.flatnonzero(on_side & (y < HIP_TOP))
            yi = y[index]
            top = max(FOOT_TOP, float(y[foot].max()) + 1e-6)    # every vertex of the foot moves with it
            shin_up = _ramp(yi, top, max(SHIN_BOTTOM, top + 0.05))  # 0 foot .. 1 shin
            thigh_up = _ramp(yi, SHIN_TOP, THIGH_BOTTOM)        # 0 shin .. 1 thigh
            body_up = _ramp(yi, THIGH_TOP, HIP_TOP)             # 0 thigh .. 1 the body (not moved)
            foot_w = 1.0 - shin_up
            shin_w = shin_up * (1.0 - thigh_up)
            thigh_w = thigh_up * (1.0 - body_up)
            rings = {name: np.flatnonzero(on_side & (y >= lo) & (y < hi)) for name, (lo, hi) in BANDS.items()}
            if any(len(r) == 0 for r in rings.values()):
                raise ValueError("the rest mesh has no vertices at a leg joint's height (is it a standing body?)")
            ring_index = np.concatenate([rings[name] for name in ("hip", "knee", "ankle")]).astype(np.int64)
            ring_bounds = np.cumsum([0] + [len(rings[name]) for name in ("hip", "knee", "ankle")]).astype(np.int64)
            self.legs.append({"index": index.astype(np.int64), "weights": np.stack([thigh_w, shin_w, foot_w], axis=1),
                              "rings": rings, "ring_index": ring_index, "ring_bounds": ring_bounds,
                              "kept": (1.0 - (thigh_w + shin_w + foot_w) + foot_w)[:, None],
                              "thigh": thigh_w[:, None].copy(), "shin": shin_w[:, None].copy()})
            hip, _, ankle = self.joints(rest, len(self.legs) - 1)
            self.legs[-1]["length"] = float(np.linalg.norm(hip - ankle))
        self.index = np.concatenate([leg["index"] for leg in self.legs])
        self._bounds_array = np.cumsum([0] + [len(leg["index"]) for leg in self.legs]).astype(np.int64)
        # every leg's rows stacked as ``index``, for the compiled move: weights (m, 3), the rest (m,)
        self._weights = np.ascontiguousarray(np.concatenate([leg["weights"] for leg in self.legs]))
        self._kept, self._thigh, self._shin = (np.concatenate([leg[name][:, 0] for leg in self.legs])
                                               for name in ("kept", "thigh", "shin"))

    def joints(self, mesh, k):
        """(3, 3) float64: the rows hip, knee, ankle of leg ``k`` on root-local ``mesh`` (the means
        of their rings of vertices)."""
        leg = self.legs[k]
        mesh = np.asarray(mesh)
        if mesh.dtype != np.float32:
            mesh = mesh.astype(np.float64, copy=False)
        return ring_means(mesh, leg["ring_index"], leg["ring_bounds"])

    def reachable(self, mesh, k, offset, joints=None):
        """The share t in [0, 1] of the root-local horizontal ``offset`` (3,) leg ``k`` can carry
        on ``mesh``: the ankle no farther from the hip than the thigh and the shin end to end (each
        longer by ``stretch`` at most), and no farther than ``cap`` x the leg's length from where
        the motion puts it. ``joints``: ``joints(mesh, k)`` if already known.

        (On Python floats, summing in numpy's order for 3-vectors: the same numbers as numpy's
        norms and dot products of them to rounding (numpy's SIMD kernels may differ in the last
        bit on another CPU), for a fraction of the calls' cost.)"""
        hip, knee, ankle = np.asarray(self.joints(mesh, k) if joints is None else joints).tolist()
        o = tuple(float(x) for x in offset)
        size = _norm(o)
        if size == 0.0:
            return 1.0
        t = min(1.0, self.cap * self.legs[k]["length"] / size)
        reach = (_norm(_sub(knee, hip)) + _norm(_sub(ankle, knee))) * (1.0 + self.stretch) * (1.0 - 1e-9)
        a = _sub(ankle, hip)
        if _norm((a[0] + t * o[0], a[1] + t * o[1], a[2] + t * o[2])) > reach:
            # |a + s o| = reach: the larger root of a quadratic
            b = a[0] * o[0] + a[1] * o[1] + a[2] * o[2]
            c = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) - reach * reach
            s = (-b + math.sqrt(max(b * b - size * size * c, 0.0))) / (size * size)
            t = min(t, max(s, 0.0))
        return float(t)

    def deform(self, mesh, offsets):
        """Move each foot of root-local ``mesh`` (n, 3) float32, in place, by the reachable part of
        its root-local horizontal offset (``offsets`` (legs, 3)), the leg following by the two-bone
        solution. Returns (legs,) the share of each offset carried (``reachable``)."""
        offsets = np.asarray(offsets, dtype=np.float64)
        shares, joints = self.reach(mesh, offsets)
        self.move(mesh, offsets, shares, joints)
        return shares

    def reach(self, mesh, offsets, known=None):
        """(shares (legs,), joints): ``reachable`` for each leg's offset on ``mesh``, and the
        joints it found (None for a leg without an offset), for ``move``. ``known``: a list (one
        entry per leg) of joints already found on this ``mesh``, None where not yet; the joints
        found here are written into it (a held frame plans its hold twice on the same mesh)."""
        shares, joints = np.ones(len(self.legs)), [None] * len(self.legs)
        for k, offset in enumerate(np.asarray(offsets, dtype=np.float64).tolist()):
            if any(offset):
                found = None if known is None else known[k]
                if found is None:
                    found = self.joints(mesh, k)
                    if known is not None:
                        known[k] = found
                joints[k] = found
                shares[k] = self.reachable(mesh, k, offset, found)
        return shares, joints

    def move(self, mesh, offsets, shares, joints):
        """``deform``'s vertex work, with ``reach``'s answer for the same ``mesh`` and ``offsets``.
        A foot's vertices move by exactly ``share x offset`` (the foot's weight is 1 there), which
        the graph player uses to read the held feet without moving the legs. Each moved leg's
        segments are mapped affinely, x -> x A + b (thigh: (x - hip) R1^T S1 + hip; shin: (x -
        knee) R2^T S2 + the new knee, S the stretch along the new bone; foot: x + share x offset),
        and a vertex takes the blend of its segments' maps by its weights, in one compiled pass
        (``engine.graph.compiled.move_legs``; a float32 C-contiguous mesh, else numpy's)."""
        found = np.zeros((len(self.legs), 3, 3))
        moved = np.zeros(len(self.legs), dtype=bool)
        for k, j in enumerate(joints):
            if j is not None:
                found[k], moved[k] = j, True
        offsets = np.ascontiguousarray(offsets, dtype=np.float64)
        shares = np.ascontiguousarray(shares, dtype=np.float64)
        if mesh.dtype == np.float32 and mesh.flags.c_contiguous and mesh.flags.writeable:
            move_legs(mesh, self.index, self._weights, self._kept, self._thigh, self._shin, self._bounds_array,
                      found, offsets, shares, moved)
        else:  # another layout: moved in a float32 copy, written back
            work = np.array(mesh, dtype=np.float32, order="C")
            self.move(work, offsets, shares, joints)
            mesh[self.index] = work[self.index]

    def segments(self, mesh):
        """(legs, 2) thigh and shin lengths (hip-knee, knee-ankle ring centroids) on ``mesh``."""
        out = np.zeros((len(self.legs), 2))
        for k in range(len(self.legs)):
            hip, knee, ankle = self.joints(mesh, k)
            out[k] = np.linalg.norm(knee - hip), np.linalg.norm(ankle - knee)
        return out

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

import numpy as np

# heights as fractions of the rest mesh's height above its lowest point (a standing human body)
BANDS = {"ankle": (0.04, 0.08), "knee": (0.26, 0.31), "hip": (0.46, 0.50)}  # hip: the pelvis, one side
FOOT_TOP, SHIN_BOTTOM = 0.03, 0.13       # foot -> shin blend
SHIN_TOP, THIGH_BOTTOM = 0.21, 0.35      # shin -> thigh blend (the knee)
THIGH_TOP, HIP_TOP = 0.36, 0.44          # thigh -> the rest of the body (below the crotch)


def _ramp(y, lo, hi):
    """Smooth step from 0 at ``lo`` to 1 at ``hi``."""
    u = np.clip((y - lo) / (hi - lo), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def rotation_between(p, q):
    """(3, 3) the smallest rotation turning the direction of ``p`` into that of ``q``."""
    p = p / np.linalg.norm(p)
    q = q / np.linalg.norm(q)
    axis = np.cross(p, q)
    s, c = float(np.linalg.norm(axis)), float(p @ q)
    if s < 1e-12:
        return np.eye(3)  # the same direction (a leg never folds back on itself here)
    k = axis / s
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def two_bone(hip, knee, ankle, target, scale=1.0, forward=(0.0, 0.0, 1.0)):
    """The knee's new place for the ankle at ``target``, the thigh and shin keeping their
    lengths times ``scale``, the knee bending in the plane it bends in now (``forward`` if the
    leg is straight). ``target`` must be within reach (no farther from the hip than the two
    lengths added)."""
    l1, l2 = scale * np.linalg.norm(knee - hip), scale * np.linalg.norm(ankle - knee)
    reach = target - hip
    d = float(np.linalg.norm(reach))
    u = reach / d
    bend = (knee - hip) - ((knee - hip) @ u) * u
    if np.linalg.norm(bend) < 1e-6 * l1:
        bend = np.asarray(forward, dtype=float) - (np.asarray(forward, dtype=float) @ u) * u
    v = bend / np.linalg.norm(bend)
    cos = np.clip((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0, 1.0)
    return hip + l1 * (cos * u + np.sqrt(1.0 - cos * cos) * v)


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
        rest = np.asarray(rest, dtype=np.float64)
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
            self.legs.append({"index": index, "weights": np.stack([thigh_w, shin_w, foot_w], axis=1),
                              "rings": rings})
            hip, _, ankle = self.joints(rest, len(self.legs) - 1)
            self.legs[-1]["length"] = float(np.linalg.norm(hip - ankle))
        self.index = np.concatenate([leg["index"] for leg in self.legs])

    def joints(self, mesh, k):
        """(hip, knee, ankle) (3,) float64 of leg ``k`` on root-local ``mesh``."""
        rings = self.legs[k]["rings"]
        return tuple(np.asarray(mesh[rings[name]], dtype=np.float64).mean(0) for name in ("hip", "knee", "ankle"))

    def reachable(self, mesh, k, offset):
        """The share t in [0, 1] of the root-local horizontal ``offset`` (3,) leg ``k`` can carry
        on ``mesh``: the ankle no farther from the hip than the thigh and the shin end to end (each
        longer by ``stretch`` at most), and no farther than ``cap`` x the leg's length from where
        the motion puts it."""
        hip, knee, ankle = self.joints(mesh, k)
        size = float(np.linalg.norm(offset))
        if size == 0.0:
            return 1.0
        t = min(1.0, self.cap * self.legs[k]["length"] / size)
        reach = (np.linalg.norm(knee - hip) + np.linalg.norm(ankle - knee)) * (1.0 + self.stretch) * (1.0 - 1e-9)
        a = ankle - hip
        if np.linalg.norm(a + t * offset) > reach:  # |a + s o| = reach: the larger root of a quadratic
            b, c = float(a @ offset), float(a @ a) - reach * reach
            s = (-b + np.sqrt(max(b * b - size * size * c, 0.0))) / (size * size)
            t = min(t, max(s, 0.0))
        return float(t)

    def deform(self, mesh, offsets):
        """Move each foot of root-local ``mesh`` (n, 3) float32, in place, by the reachable part of
        its root-local horizontal offset (``offsets`` (legs, 3)), the leg following by the two-bone
        solution. Returns (legs,) the share of each offset carried (``reachable``)."""
        shares = np.ones(len(self.legs))
        for k, (leg, offset) in enumerate(zip(self.legs, np.asarray(offsets, dtype=np.float64))):
            if not offset.any():
                continue
            t = shares[k] = self.reachable(mesh, k, offset)
            if t == 0.0:
                continue
            hip, knee, ankle = self.joints(mesh, k)
            target = ankle + t * offset
            scale = max(1.0, float(np.linalg.norm(target - hip)) / (np.linalg.norm(knee - hip) + np.linalg.norm(ankle - knee)))
            new_knee = two_bone(hip, knee, ankle, target, scale)
            R1 = rotation_between(knee - hip, new_knee - hip)
            R2 = rotation_between(ankle - knee, target - new_knee)
            x = np.asarray(mesh[leg["index"]], dtype=np.float64)
            thigh = (x - hip) @ R1.T
            shin = (x - knee) @ R2.T
            if scale > 1.0:  # lengthened along the bones only
                e1, e2 = (new_knee - hip) / np.linalg.norm(new_knee - hip), (target - new_knee) / np.linalg.norm(target - new_knee)
                thigh += (scale - 1.0) * (thigh @ e1)[:, None] * e1
                shin += (scale - 1.0) * (shin @ e2)[:, None] * e2
            thigh += hip
            shin += new_knee
            foot = x + t * offset
            w = leg["weights"]
            moved = x * (1.0 - w.sum(1))[:, None] + w[:, :1] * thigh + w[:, 1:2] * shin + w[:, 2:] * foot
            mesh[leg["index"]] = moved
        return shares

    def segments(self, mesh):
        """(legs, 2) thigh and shin lengths (hip-knee, knee-ankle ring centroids) on ``mesh``."""
        out = np.zeros((len(self.legs), 2))
        for k in range(len(self.legs)):
            hip, knee, ankle = self.joints(mesh, k)
            out[k] = np.linalg.norm(knee - hip), np.linalg.norm(ankle - knee)
        return out

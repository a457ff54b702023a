"""Retargeting CMU takes (CC_Base rig) onto the studio body's MakeHuman skeleton.

Every studio joint copies the world rotation of one CC_Base joint (twist and share bones are
folded away: the main bone of each limb carries its full rotation) through a constant
calibration found on the T-pose that opens takes 007_04 and 007_12: at that frame the body
stands in its own rest pose with the arms raised to the horizontal, so the retargeted joint
rotation is ``R_b(t) = G Rm_b(t) Rm_b(T)^T S_b`` with ``S_b`` the rest -> T-pose rotation of the
body's bone and ``G`` the turn that makes the take start facing +Z at the origin. Joint positions
follow from the body's own bone lengths (forward kinematics from the pelvis), the pelvis from the
actor's hip scaled by the ratio of leg lengths.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from engine.rotations import matrix_to_quaternion, rot_y
from engine.synthetic.studio.assets import BVH_UNITS, mocap_take
from engine.synthetic.studio.bvh import forward_kinematics

CC_JOINT = {
    "pelvis": "CC_Base_Pelvis", "spine_01": "CC_Base_Waist", "spine_02": "CC_Base_Spine01",
    "spine_03": "CC_Base_Spine02", "neck_01": "CC_Base_NeckTwist01", "head": "CC_Base_Head",
    **{f"{part}_{s}": f"CC_Base_{s.upper()}_{cc}" for s in "lr" for part, cc in (
        ("clavicle", "Clavicle"), ("upperarm", "Upperarm"), ("lowerarm", "Forearm"), ("hand", "Hand"),
        ("thigh", "Thigh"), ("calf", "Calf"), ("foot", "Foot"), ("ball", "ToeBase"))},
}
T_POSE = ("007_04", 0)  # take and frame of the converter's T-pose
FEET = tuple(f"CC_Base_{s}_{j}" for s in "LR" for j in ("Foot", "ToeBase"))  # ground contact


@dataclass
class SkeletonMotion:
    """Studio skeleton poses over time.

    Attributes
    ----------
    fps : float
    rotations : (frames, J, 3, 3) float array   world rotation of each joint (rest -> posed)
    positions : (frames, J, 3) float array      world joint positions (metres)
    source : str                                where the motion comes from
    clearance : (frames,) float array or None   how far the actor's lowest foot joint is above
                                                where it is when planted (m, body scale):
                                                0 on the ground, > 0 in flight; None: always 0
    """

    fps: float
    rotations: np.ndarray
    positions: np.ndarray
    source: str
    clearance: np.ndarray | None = None

    @property
    def frames(self):
        return len(self.rotations)

    def ground_clearance(self):
        return np.zeros(self.frames) if self.clearance is None else self.clearance


def quaternion_to_matrix(q):
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) (w, x, y, z)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def blend_rotations(A, B, weight):
    """Normalised quaternion interpolation between rotation arrays (frames, J, 3, 3)."""
    qa, qb = matrix_to_quaternion(A), matrix_to_quaternion(B)
    qb = np.where(np.sum(qa * qb, axis=-1, keepdims=True) < 0, -qb, qb)
    weight = np.asarray(weight, dtype=float).reshape((-1,) + (1,) * (qa.ndim - 1))
    return quaternion_to_matrix((1 - weight) * qa + weight * qb)


def _swing(a, b):
    """The smallest rotation taking direction a onto direction b."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def t_pose(skeleton):
    """(J, 3, 3) rotations taking the body's rest bones to a T-pose (arms level, elbows straight).

    Only the arms move; the elbow straightens about its own hinge and the hand stays in line
    with the forearm.
    """
    S = np.tile(np.eye(3), (len(skeleton.names), 1, 1))

    def direction(name):
        j = skeleton.index(name)
        return skeleton.tails[j] - skeleton.rest[j]

    for side, sign in (("l", 1.0), ("r", -1.0)):
        upper, lower, hand = (skeleton.index(f"{b}_{side}") for b in ("upperarm", "lowerarm", "hand"))
        S[upper] = _swing(direction(f"upperarm_{side}"), np.array([sign, 0.0, 0.0]))
        S[lower] = S[upper] @ _swing(direction(f"lowerarm_{side}"), direction(f"upperarm_{side}"))
        S[hand] = S[lower] @ _swing(direction(f"hand_{side}"), direction(f"lowerarm_{side}"))
    return S


@lru_cache(maxsize=4)
def _calibration(skeleton):
    take, frame = T_POSE
    bvh = mocap_take(take)
    R, P = forward_kinematics(bvh, slice(frame, frame + 1))
    cc = np.array([R[0, bvh.index(CC_JOINT[name])] for name in skeleton.names])
    K = np.einsum("jba,jbc->jac", cc, t_pose(skeleton))
    leg = sum(np.linalg.norm(bvh.offsets[bvh.index(f"CC_Base_L_{j}")]) for j in ("Calf", "Foot")) * BVH_UNITS
    body_leg = (np.linalg.norm(skeleton.position("calf_l") - skeleton.position("thigh_l"))
                + np.linalg.norm(skeleton.position("foot_l") - skeleton.position("calf_l")))
    hip_height = P[0, bvh.index("CC_Base_Hip"), 1] * BVH_UNITS
    return K, body_leg / leg, hip_height


@lru_cache(maxsize=16)
def _planted_feet(take):
    """The take's foot and toe joints and their heights when planted (5th percentile, file units)."""
    bvh = mocap_take(take)
    feet = [bvh.index(name) for name in FEET]
    first = 1 if take.startswith("007_") else 0
    return feet, np.percentile(forward_kinematics(bvh, slice(first, None))[1][:, feet, 1], 5, axis=0)


def body_forward_kinematics(skeleton, rotations, root):
    """Joint positions (frames, J, 3) from world rotations and the pelvis position (frames, 3)."""
    rotations = np.asarray(rotations, dtype=float)
    P = np.empty(rotations.shape[:2] + (3,))
    P[:, 0] = root
    for j in range(1, len(skeleton.names)):
        p = skeleton.parents[j]
        P[:, j] = P[:, p] + rotations[:, p] @ (skeleton.rest[j] - skeleton.rest[p])
    return P


def _facing(R_pelvis):
    """Heading (radians about +Y, 0 = +Z) of pelvis rotations (frames, 3, 3)."""
    forward = R_pelvis[:, :, 2]
    return np.arctan2(forward[:, 0], forward[:, 2])


def retarget(skeleton, take, *, fps, start=0.0, stop=None):
    """A CMU take on the studio skeleton, resampled to ``fps``, starting at the origin facing +Z.

    Parameters
    ----------
    skeleton : StudioSkeleton
    take : str             e.g. "002_05" (see assets.TAKES); the T-pose frame of 007_* is skipped
    fps : float            output frame rate
    start, stop : float    seconds into the take (stop None: to the end)

    Returns
    -------
    motion : SkeletonMotion
    """
    bvh = mocap_take(take)
    first = 1 if take.startswith("007_") else 0
    feet, planted = _planted_feet(take)
    K, scale, hip_height = _calibration(skeleton)
    duration = (bvh.frames - 1 - first) * bvh.frame_time
    stop = duration if stop is None else min(stop, duration)
    if not 0 <= start < stop:
        raise ValueError(f"take {take}: need 0 <= start < stop <= {duration:.2f} s, got {start}, {stop}")
    times = start + np.arange(int(np.floor((stop - start) * fps + 1e-9)) + 1) / fps
    position = times / bvh.frame_time + first
    lo = np.clip(np.floor(position).astype(int), first, bvh.frames - 1)
    hi = np.minimum(lo + 1, bvh.frames - 1)
    needed = np.unique(np.concatenate([lo, hi]))
    R, P = forward_kinematics(bvh, needed)
    row = {f: i for i, f in enumerate(needed)}
    lo_rows, hi_rows = np.array([row[f] for f in lo]), np.array([row[f] for f in hi])
    cc = [bvh.index(CC_JOINT[name]) for name in skeleton.names]
    weight = position - lo
    Rw = blend_rotations(R[lo_rows][:, cc], R[hi_rows][:, cc], weight)
    hip = bvh.index("CC_Base_Hip")
    Ph = (1 - weight)[:, None] * P[lo_rows, hip] + weight[:, None] * P[hi_rows, hip]
    Pf = (1 - weight)[:, None] * P[lo_rows][:, feet, 1] + weight[:, None] * P[hi_rows][:, feet, 1]
    clearance = np.clip(scale * BVH_UNITS * (Pf - planted).min(axis=1), 0.0, None)
    rotations = np.einsum("fjab,jbc->fjac", Rw, K)
    early = rotations[: max(1, int(fps)), 0, :, 2].mean(axis=0)  # the pelvis sways: face its mean over 1 s
    G = rot_y(-np.arctan2(early[0], early[2]))
    rotations = np.einsum("ab,fjbc->fjac", G, rotations)
    # The pelvis moves as the actor's hip, scaled by the leg lengths, from where it stood in the
    # T-pose (vertically) and from the take's first frame (horizontally).
    offset = Ph * BVH_UNITS - np.array([Ph[0, 0] * BVH_UNITS, hip_height, Ph[0, 2] * BVH_UNITS])
    root = skeleton.rest[0] + scale * offset @ G.T
    positions = body_forward_kinematics(skeleton, rotations, root)
    return SkeletonMotion(fps=float(fps), rotations=rotations, positions=positions,
                          source=f"CMU {take} {start:.2f}-{stop:.2f} s", clearance=clearance)


def concatenate(skeleton, motions, blend=0.4):
    """Play motions one after the other, each continuing where and facing as the last one ended.

    The last ``blend`` seconds of a motion and the first of the next are cross-faded
    (quaternion blend of the joint rotations, linear blend of the pelvis).
    """
    out = motions[0]
    for nxt in motions[1:]:
        n = max(1, int(round(blend * out.fps)))
        turn = _facing(out.rotations[-n:][:1, 0])[0] - _facing(nxt.rotations[:1, 0])[0]  # ([-1:0] is empty)
        G = rot_y(turn)
        rotations = np.einsum("ab,fjbc->fjac", G, nxt.rotations)
        root = (nxt.positions[:, 0] - nxt.positions[0, 0]) @ G.T
        root[:, 1] += nxt.positions[0, 0, 1]
        root[:, [0, 2]] += out.positions[-n, 0, [0, 2]]
        w = 0.5 - 0.5 * np.cos(np.pi * (np.arange(n) + 1) / (n + 1))
        mixed_R = blend_rotations(out.rotations[-n:], rotations[:n], w)
        mixed_root = (1 - w)[:, None] * out.positions[-n:, 0] + w[:, None] * root[:n]
        all_R = np.concatenate([out.rotations[:-n], mixed_R, rotations[n:]])
        all_root = np.concatenate([out.positions[:-n, 0], mixed_root, root[n:]])
        a, b = out.ground_clearance(), nxt.ground_clearance()
        clearance = np.concatenate([a[:-n], (1 - w) * a[-n:] + w * b[:n], b[n:]])
        out = SkeletonMotion(out.fps, all_R, body_forward_kinematics(skeleton, all_R, all_root),
                             f"{out.source} + {nxt.source}", clearance)
    return out


def root_trajectory(motion):
    """Root on the ground (frames, 3) and heading (frames,) radians about +Y (0 = +Z, + = left)."""
    root = motion.positions[:, 0].copy()
    root[:, 1] = 0.0
    return root, np.unwrap(_facing(motion.rotations[:, 0]))

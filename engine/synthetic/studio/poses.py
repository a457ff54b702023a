"""Key-framed poses of the studio skeleton: contacts (hands on hips, arms crossed, a knee to the
chest) and reaches, posed by two-bone IK on the MakeHuman rig.

A key pose is the local rotation of every joint (relative to its parent, rest frames world
aligned) and the pelvis position; a sequence eases between keys with minimum-jerk timing and a
little idle sway, so no two frames are exactly alike.
"""

from __future__ import annotations

import numpy as np

from engine.rotations import frame_from_direction, rot_x, rot_z
from engine.synthetic.kinematics import minimum_jerk, two_bone_ik
from engine.synthetic.studio.retarget import (
    SkeletonMotion,
    blend_rotations,
    body_forward_kinematics,
)

SIDES = (("l", 1.0), ("r", -1.0))


def _world(skeleton, local):
    R = np.empty_like(local)
    for j, p in enumerate(skeleton.parents):
        R[j] = local[j] if p < 0 else R[p] @ local[j]
    return R


def _local(skeleton, R):
    L = np.empty_like(R)
    for j, p in enumerate(skeleton.parents):
        L[j] = R[j] if p < 0 else R[p].T @ R[j]
    return L


def _limb_rotations(skeleton, upper, lower, upper_dir, lower_dir):
    """World rotations of a two-bone limb bent in the plane of the given directions."""
    def hinge(a, b, fallback):
        h = np.cross(a, b)
        n = np.linalg.norm(h)
        return h / n if n > 1e-6 else fallback

    iu, il = skeleton.index(upper), skeleton.index(lower)
    rest_u = skeleton.rest[il] - skeleton.rest[iu]
    rest_l = skeleton.tails[il] - skeleton.rest[il]
    rest_h = hinge(rest_u, rest_l, np.array([1.0, 0.0, 0.0]))
    h = hinge(upper_dir, lower_dir, rest_h)

    def rotation(d, d_rest):
        return frame_from_direction(d, np.cross(h, d)) @ frame_from_direction(d_rest, np.cross(rest_h, d_rest)).T

    return rotation(upper_dir, rest_u), rotation(lower_dir, rest_l)


def key_pose(skeleton, name, **params):
    """Local joint rotations (J, 3, 3) and pelvis position (3,) of a named pose.

    Names: "stand", "hands_on_hips", "arms_crossed", "knee_to_chest" (the left knee),
    "reach" (params: height of the right wrist in metres, forward distance).
    """
    J = len(skeleton.names)
    local = np.tile(np.eye(3), (J, 1, 1))
    root = skeleton.rest[0].copy()
    ix = skeleton.index
    flex = {"knee_to_chest": 18.0, "reach": 0.0}.get(name, 0.0)
    if name == "reach":
        height = params.get("height", 1.3)
        flex = float(np.clip((1.05 - height) / 0.35, 0.0, 1.0)) * 40.0
        root[1] -= float(np.clip((1.0 - height) / 0.3, 0.0, 1.0)) * 0.12
    for bone, share in (("spine_01", 0.3), ("spine_02", 0.35), ("spine_03", 0.35)):
        local[ix(bone)] = rot_x(np.radians(flex * share))
    local[ix("head")] = rot_x(np.radians(0.5 * flex))
    R = _world(skeleton, local)
    P = body_forward_kinematics(skeleton, R[None], root[None])[0]
    targets, poles = {}, {}
    pelvis, chest = P[ix("pelvis")], P[ix("spine_03")]
    for side, sign in SIDES:
        shoulder = P[ix(f"upperarm_{side}")]
        poles[side] = np.array([0.3 * sign, 0.0, -1.0])
        targets[side] = shoulder + np.array([0.07 * sign, -0.46, 0.08])
        if name == "hands_on_hips":
            targets[side] = pelvis + np.array([0.15 * sign, 0.17, -0.02])
            poles[side] = np.array([sign, 0.2, -0.6])
        elif name == "arms_crossed":
            targets[side] = chest + np.array([-0.13 * sign, 0.05 + 0.03 * sign, 0.17])
            poles[side] = np.array([sign, -0.8, -0.2])
        elif name == "knee_to_chest":
            targets[side] = np.array([0.1 + 0.07 * sign, 0.88, 0.40])
            poles[side] = np.array([sign, 0.0, -0.3])
        elif name == "reach" and side == "r":
            targets[side] = np.array([-0.17, params.get("height", 1.3), params.get("forward", 0.42)])
            poles[side] = np.array([-0.5, -0.7, -0.5])
    for side, sign in SIDES:
        upper, lower = f"upperarm_{side}", f"lowerarm_{side}"
        lengths = [np.linalg.norm(skeleton.rest[ix(lower)] - skeleton.rest[ix(upper)]),
                   np.linalg.norm(skeleton.rest[ix(f"hand_{side}")] - skeleton.rest[ix(lower)])]
        up_dir, low_dir, _, _ = two_bone_ik(P[ix(upper)][None], targets[side][None], *lengths, poles[side][None])
        R[ix(upper)], R[ix(lower)] = _limb_rotations(skeleton, upper, lower, up_dir[0], low_dir[0])
        R[ix(f"hand_{side}")] = R[ix(lower)]
        thigh, calf = f"thigh_{side}", f"calf_{side}"
        if name == "knee_to_chest" and side == "l":
            R[ix(thigh)] = rot_x(np.radians(-110.0))
            R[ix(calf)] = R[ix(thigh)] @ rot_x(np.radians(125.0))
        else:
            foot = skeleton.rest[ix(f"foot_{side}")]
            lengths = [np.linalg.norm(skeleton.rest[ix(calf)] - skeleton.rest[ix(thigh)]),
                       np.linalg.norm(foot - skeleton.rest[ix(calf)])]
            hip = body_forward_kinematics(skeleton, R[None], root[None])[0][ix(thigh)]
            up_dir, low_dir, _, _ = two_bone_ik(hip[None], foot[None], *lengths, np.array([[0.0, 0.0, 1.0]]))
            R[ix(thigh)], R[ix(calf)] = _limb_rotations(skeleton, thigh, calf, up_dir[0], low_dir[0])
        R[ix(f"foot_{side}")] = np.eye(3) if not (name == "knee_to_chest" and side == "l") else R[ix(calf)]
        R[ix(f"ball_{side}")] = R[ix(f"foot_{side}")]
    return _local(skeleton, R), root


def pose_sequence(skeleton, keys, *, fps, seed=0, source="poses"):
    """Ease between key poses.

    Parameters
    ----------
    keys : list of (time_s, name, params dict)   increasing times; held outside their range
    fps : float
    seed : int   phase of the idle sway

    Returns
    -------
    motion : SkeletonMotion
    """
    rng = np.random.default_rng(seed)
    times = np.array([k[0] for k in keys], dtype=float)
    poses = [key_pose(skeleton, name, **params) for _, name, params in keys]
    t = np.arange(int(np.floor(times[-1] * fps + 1e-9)) + 1) / fps
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    u = minimum_jerk((t - times[i]) / (times[i + 1] - times[i]))
    L0 = np.stack([poses[k][0] for k in i])
    L1 = np.stack([poses[k + 1][0] for k in i])
    local = blend_rotations(L0, L1, u)
    root = np.stack([poses[k][1] for k in i]) * (1 - u)[:, None] + np.stack([poses[k + 1][1] for k in i]) * u[:, None]
    phase = rng.uniform(0, 2 * np.pi, 3)
    sway = np.radians(2.0) * np.sin(2 * np.pi * 0.35 * t + phase[0])
    local[:, skeleton.index("spine_02")] = local[:, skeleton.index("spine_02")] @ rot_z(sway)
    local[:, skeleton.index("neck_01")] = local[:, skeleton.index("neck_01")] @ rot_x(
        np.radians(3.0) * np.sin(2 * np.pi * 0.27 * t + phase[1]))
    root = root + 0.008 * np.stack([np.sin(2 * np.pi * 0.2 * t + phase[2]), np.zeros_like(t), np.zeros_like(t)], 1)
    R = np.empty_like(local)
    for j, p in enumerate(skeleton.parents):
        R[:, j] = local[:, j] if p < 0 else R[:, p] @ local[:, j]
    return SkeletonMotion(fps=float(fps), rotations=R, positions=body_forward_kinematics(skeleton, R, root),
                          source=source)


CONTACT_KEYS = [(0.0, "stand", {}), (0.8, "hands_on_hips", {}), (1.6, "hands_on_hips", {}), (2.4, "stand", {}),
                (3.2, "arms_crossed", {}), (4.0, "arms_crossed", {}), (4.8, "stand", {}),
                (5.8, "knee_to_chest", {}), (6.6, "knee_to_chest", {}), (7.6, "stand", {}), (8.0, "stand", {})]


def reach_keys(height, forward=0.42):
    """Stand, reach the right wrist to ``height`` in front, hold, come back."""
    reach = {"height": height, "forward": forward}
    return [(0.0, "stand", {}), (0.3, "stand", {}), (1.1, "reach", reach), (1.5, "reach", reach),
            (2.3, "stand", {}), (2.6, "stand", {})]

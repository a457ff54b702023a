"""Synthetic performance captures: animated body surfaces with ground truth.

``animate`` turns a Motion into a vertex sequence (skinning plus secondary dynamics);
``make_sequence`` builds one named capture from a ``SequenceSpec``, calibrating jumps and reaches
so that the parameters measured on the meshes (``engine.measures``) match the request.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from engine import measures
from engine.rotations import rot_y
from engine.synthetic import motions, transitions
from engine.synthetic.dynamics import GARMENT, SOFT_TISSUE, secondary_motion
from engine.synthetic.remesh import remesh_frame
from engine.synthetic.skinning import skin_dual_quaternion

PALM_OFFSET = 0.07  # wrist to palm centre along the forearm (reference body, m)


def _skin(body, rotations, positions):
    return skin_dual_quaternion(body.V, body.skeleton.rest, rotations, positions, body.weight_index, body.weight)


def animate(body, motion):
    """Surface of ``body`` performing ``motion``: dual-quaternion skinning + soft tissue + garment.

    Parameters
    ----------
    body : Body
    motion : Motion

    Returns
    -------
    V : (frames, n, 3) float array

    Notes
    -----
    A cyclic motion's dynamics are the periodic steady state over one cycle evaluated from the
    clip's first frame, so frame k + N equals frame k moved by one cycle's root motion.
    """
    V = _skin(body, motion.rotations, motion.positions)
    amplitudes = {SOFT_TISSUE: body.soft_tissue, GARMENT: body.garment}
    dt = 1.0 / motion.fps
    if motion.cyclic:
        N = motion.frames_per_cycle
        t_cycle = motion.times[0] + np.arange(-1, N + 1) * dt  # one cycle and its true neighbours
        R, P, _, heading_cycle = motion.pose_at(t_cycle)
        skinned = _skin(body, R, P)
        local = secondary_motion(skinned[1:-1], heading_cycle[1:-1], motion.fps, amplitudes, periodic=True,
                                 before=skinned[0], after=skinned[-1], world=False)
        local = local[np.arange(len(V)) % N]
    else:
        ends = np.array([motion.times[0] - dt, motion.times[-1] + dt])
        R, P, _, _ = motion.pose_at(ends)
        before, after = _skin(body, R, P)
        local = secondary_motion(V, motion.heading, motion.fps, amplitudes, periodic=False,
                                 before=before, after=after, world=False)
    return V + np.einsum("fab,fnb->fna", rot_y(motion.heading), local)


@dataclass(frozen=True)
class SequenceSpec:
    """One capture to generate.

    kind "gait": params speed (m/s), turn_rate (deg/s), cycles
    kind "jump": params height (m, centre-of-mass rise), distance (m)
    kind "reach": params height (m, palm centre), side ("l"/"r")
    kind "stand": params period (s), breath (m), sway (m), cycles: a standing idle
    kind "gait_stop" / "gait_start": params speed (m/s), walk, ramp, hold (s): a walk that stops
        to the standing pose / sets off from it
    kind "performance": params speed (m/s), height, distance (m), walk (s): the true continuous
        walk, stop, jump, start, walk a motion graph imitates
    """

    name: str
    kind: str
    params: dict = field(default_factory=dict)


def _secant(f, target, x0, x1, lo, hi, tol=2e-4, iterations=8):
    """Solve f(x) = target for monotone f by the secant method, clamped to [lo, hi]."""
    y0 = f(x0) - target
    x, y = x1, f(x1) - target
    for _ in range(iterations):
        if abs(y) < tol:
            break
        slope = (y - y0) / (x - x0) if x != x0 else 1.0
        x0, y0 = x, y
        x = float(np.clip(x - y / (slope if abs(slope) > 1e-6 else 1.0), lo, hi))
        y = f(x) - target
    return x


def _jump_rise(body, height, distance, fps):
    """The flight rise whose jump's centre of mass rises ``height`` metres (measured on meshes)."""

    def measured_height(rise):
        V = animate(body, motions.jump(body.skeleton, rise, distance, fps=fps, palm_offset=PALM_OFFSET))
        return measures.jump_height(measures.centre_of_mass(V, body.F))

    return _secant(measured_height, height, height, 0.9 * height, 0.02, 0.9)


def _travel(V, F, motion, fps):
    """What a walk that stops or starts measures: its centre of mass's horizontal travel (m) and
    its speed over the first (stop) or last (start) second."""
    com = measures.centre_of_mass(V, F)
    travel = float(np.linalg.norm(com[-1, [0, 2]] - com[0, [0, 2]]))
    span = max(2, min(len(com) - 1, int(round(fps))))
    piece = com[:span + 1] if motion.kind != "gait_start" else com[-span - 1:]
    speed = float(np.linalg.norm(piece[-1, [0, 2]] - piece[0, [0, 2]]) * fps / span)
    return {"travel": travel, "speed": speed}


def make_sequence(body, spec, *, fps=30.0, seed=0):
    """Generate one consistent-topology capture with its measured parameters.

    Parameters
    ----------
    body : Body
    spec : SequenceSpec
    fps : float
    seed : int   chooses the starting phase of gaits

    Returns
    -------
    motion : Motion
    V : (frames, n, 3) float array
    measured : dict   parameters measured on V (engine.measures definitions)
    """
    sk = body.skeleton
    rng = np.random.default_rng(seed)
    p = spec.params
    if spec.kind == "gait":
        motion = motions.gait(sk, p["speed"], turn_rate=p.get("turn_rate", 0.0), fps=fps,
                              cycles=p.get("cycles", 2.0), start_phase=p.get("start_phase", rng.uniform(0, 1)),
                              name=spec.name, palm_offset=PALM_OFFSET)
        V = animate(body, motion)
        N = motion.frames_per_cycle
        probe = V
        if len(V) < N + 3:  # too short to measure a cycle: measure the same motion for longer
            longer = motions.gait(sk, p["speed"], turn_rate=p.get("turn_rate", 0.0), fps=fps,
                                  cycles=(N + 3) / N, start_phase=motion.times[0] / motion.params["period"],
                                  palm_offset=PALM_OFFSET)
            probe = animate(body, longer)
        com = measures.centre_of_mass(probe, body.F)
        speed, turn = measures.gait_speed_and_turn_rate(com, fps, N)
        measured = {"speed": speed, "turn_rate": turn}
    elif spec.kind == "jump":
        height, distance = p["height"], p["distance"]
        rise = _jump_rise(body, height, distance, fps)
        motion = motions.jump(sk, rise, distance, fps=fps, name=spec.name, palm_offset=PALM_OFFSET)
        V = animate(body, motion)
        com = measures.centre_of_mass(V, body.F)
        measured = {"height": measures.jump_height(com), "distance": measures.jump_distance(com)}
        motion.params.update({"height": height})
    elif spec.kind == "stand":
        motion = transitions.stand(sk, period=p.get("period", 2.0), breath=p.get("breath", 0.008),
                                   sway=p.get("sway", 0.0), cycles=p.get("cycles", 1.0), fps=fps, name=spec.name,
                                   palm_offset=PALM_OFFSET)
        V = animate(body, motion)
        com = measures.centre_of_mass(V, body.F)
        measured = {"com_bob": float(np.ptp(com[:, 1])), "com_sway": float(np.ptp(com[:, 0]))}
    elif spec.kind in ("gait_stop", "gait_start"):
        motion = transitions.walk_transition(sk, p["speed"], spec.kind[5:], walk=p.get("walk", 1.0),
                                             ramp=p.get("ramp", 1.2), hold=p.get("hold", 0.4), fps=fps,
                                             name=spec.name, palm_offset=PALM_OFFSET)
        V = animate(body, motion)
        measured = _travel(V, body.F, motion, fps)
    elif spec.kind == "performance":
        rise = _jump_rise(body, p["height"], p["distance"], fps)
        motion = transitions.performance(sk, p["speed"], rise, p["distance"], walk=p.get("walk", 1.0), fps=fps,
                                         name=spec.name, palm_offset=PALM_OFFSET)
        V = animate(body, motion)
        measured = _travel(V, body.F, motion, fps)
        motion.params.update({"height": p["height"]})
    elif spec.kind == "reach":
        side = p.get("side", "r")
        hand = body.hand_vertices(side)

        def run(target):
            m = motions.reach(sk, target, side=side, fps=fps, name=spec.name, palm_offset=PALM_OFFSET)
            return m, animate(body, m)

        lo, hi = 0.5 * sk.scale, 2.1 * sk.scale
        target = _secant(lambda x: measures.reach_height(run(x)[1], hand), p["height"],
                         p["height"], p["height"] + 0.02, lo, hi)
        motion, V = run(target)
        measured = {"height": measures.reach_height(V, hand)}
        motion.params.update({"height": p["height"]})
    else:
        raise ValueError(f"unknown sequence kind {spec.kind!r}; expected gait, jump, reach, stand, "
                         "gait_stop, gait_start or performance")
    return motion, V, measured


def unstructured_capture(V, F, colors, *, seed=0, noise=0.001, vertex_ratio=(0.85, 1.15), progress=None):
    """Re-mesh every frame independently (see ``remesh_frame``).

    Returns
    -------
    frames : list of (V_k, F_k, colors_k)
    """
    out = []
    for k in range(len(V)):
        out.append(remesh_frame(V[k], F, colors, seed=seed * 100_003 + k, noise=noise, vertex_ratio=vertex_ratio))
        if progress is not None:
            progress(k + 1, len(V))
    return out


def generate_sequence_data(body, spec, *, fps=30.0, noise_mm=1.0, seed=0, unstructured=True, progress=None):
    """Everything one capture sequence needs on disk, as arrays and JSON-friendly metadata.

    Parameters
    ----------
    body : Body
    spec : SequenceSpec
    fps : float
    noise_mm : float          reconstruction noise of the unstructured frames (standard deviation)
    seed : int
    unstructured : bool       also re-mesh every frame independently
    progress : callable(done, total) or None   called per re-meshed frame

    Returns
    -------
    data : dict with
        vertices : (frames, n, 3) float array   consistent-topology frames (the true surface)
        unstructured : list of (V_k, F_k, colors_k) or None
        truth : dict of arrays (root_position, heading, joint_positions, joint_rotations,
                template_positions = vertices as float32, times)
        meta : dict (name, kind, fps, frames, cyclic, frames_per_cycle, requested, measured, events,
               unstructured vertex counts, noise)
    """
    motion, V, measured = make_sequence(body, spec, fps=fps, seed=seed)
    frames = None
    if unstructured:
        frames = unstructured_capture(V, body.F, body.colors, seed=seed, noise=noise_mm / 1000.0,
                                      progress=progress)
    requested = {k: v for k, v in spec.params.items() if k not in ("cycles", "start_phase", "side")}
    meta = {
        "name": spec.name, "kind": spec.kind, "fps": fps, "frames": int(len(V)),
        "duration": float(len(V) / fps), "cyclic": motion.cyclic,
        "frames_per_cycle": motion.frames_per_cycle,
        "requested": requested, "measured": measured,
        "motion_params": {k: v for k, v in motion.params.items()},
        "events": motion.events, "seed": seed, "noise_mm": noise_mm,
        "unstructured_vertex_counts": [int(len(f[0])) for f in frames] if frames else None,
    }
    truth = {
        "times": motion.times, "root_position": motion.root_position, "heading": motion.heading,
        "joint_positions": motion.positions, "joint_rotations": motion.rotations,
        "template_positions": V.astype(np.float32),
    }
    return {"vertices": V, "unstructured": frames, "truth": truth, "meta": meta}

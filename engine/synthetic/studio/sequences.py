"""Studio sequences: motion (retargeted CMU takes or key-framed poses) -> the dressed body's true
surface with garment dynamics -> ground truth, metadata and per-frame reconstructions.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d

from engine import measures
from engine.synthetic.dynamics import SOFT_TISSUE, Material, secondary_motion
from engine.synthetic.skinning import skin_dual_quaternion
from engine.synthetic.studio.axes import axes_record
from engine.synthetic.studio.garment import push_out_of_capsules
from engine.synthetic.studio.poses import pose_sequence
from engine.synthetic.studio.reconstruct import (
    StudioCamera,
    contact_vertices,
    reconstruct_frame,
)
from engine.synthetic.studio.retarget import concatenate, retarget, root_trajectory

LOOSE_GARMENT = Material(frequency=1.5, damping=0.2, cap=0.10)  # skirt and sleeves lag the body
KINDS = ("gait", "jump", "reach", "performance", "contact")


@dataclass(frozen=True)
class StudioSequenceSpec:
    """One studio capture.

    name : str
    kind : "gait", "jump", "reach", "performance" (long takes) or "contact" (posed contacts)
    takes : tuple of (take, start_s, stop_s or None)   CMU takes played one after the other
    keys : tuple of (time_s, pose, params)   key poses (instead of takes), see ``poses``
    units, up : the files' units ("m", "mm") and up axis ("+Y", "+Z"); the truth stays m, +Y
    """

    name: str
    kind: str
    takes: tuple = ()
    keys: tuple = ()
    units: str = "m"
    up: str = "+Y"
    params: dict = field(default_factory=dict)


def studio_motion(skeleton, spec, *, fps, seed=0):
    """The skeleton motion of a sequence (SkeletonMotion)."""
    if spec.kind not in KINDS:
        raise ValueError(f"unknown studio sequence kind {spec.kind!r}; expected one of {', '.join(KINDS)}")
    if spec.takes:
        motions = [retarget(skeleton, take, fps=fps, start=start, stop=stop) for take, start, stop in spec.takes]
        return concatenate(skeleton, motions) if len(motions) > 1 else motions[0]
    if spec.keys:
        return pose_sequence(skeleton, list(spec.keys), fps=fps, seed=seed, source=f"key poses ({spec.kind})")
    raise ValueError(f"sequence {spec.name}: needs takes or key poses")


def animate_studio(body, motion):
    """The dressed body's true surface over a motion.

    Skinning (dual quaternions), then a vertical correction per frame that puts the lowest foot
    point where the actor's feet were (on the ground, or as high as the flight) and nothing below
    the floor, then soft tissue and the garments' lag (damped springs driven by the
    accelerations, starting and ending at rest), and last the legs pushing the skirt aside
    (its points moved out of tapered capsules around the thighs and shins).

    Returns
    -------
    V : (frames, n, 3) float array
    positions : (frames, J, 3) float array   joint positions with the same correction
    """
    sk = body.skeleton
    V = skin_dual_quaternion(body.V, sk.rest, motion.rotations, motion.positions, body.weight_index, body.weight)
    on_body = body.part == 0
    feet = np.flatnonzero(on_body & np.isin(body.segment, [sk.index(f"{b}_{s}") for b in ("foot", "ball")
                                                            for s in "lr"]))
    lowest_feet = V[:, feet, 1].min(axis=1)
    lowest = V[:, on_body, 1].min(axis=1)
    lift = np.maximum(motion.ground_clearance() - lowest_feet, -lowest)
    if len(lift) > 2:
        lift = np.maximum(gaussian_filter1d(lift, 1.0, mode="nearest"), -lowest)
    V[:, :, 1] += lift[:, None]
    positions = motion.positions.copy()
    positions[:, :, 1] += lift[:, None]
    if len(V) > 1:
        D = secondary_motion(V, np.zeros(len(V)), motion.fps,
                             {SOFT_TISSUE: body.soft_tissue, LOOSE_GARMENT: body.garment}, periodic=False,
                             before=2 * V[0] - V[1], after=2 * V[-1] - V[-2], world=True)
        V += D
    if body.capsules:  # the legs push the skirt aside
        skirt = np.flatnonzero(body.part == 1)
        heads = positions[:, [c[0] for c in body.capsules]]
        tails = positions[:, [c[1] for c in body.capsules]]
        radii = np.array([c[2:] for c in body.capsules])
        V[:, skirt] = push_out_of_capsules(V[:, skirt], heads, tails, radii, body.clearance[skirt])
    return V, positions


def _measured(body, spec, V, motion, root, heading):
    duration = max(len(V) - 1, 1) / motion.fps
    if spec.kind == "gait":
        return {"speed": float(np.linalg.norm(root[-1] - root[0]) / duration),
                "turn_rate": float(np.degrees(heading[-1] - heading[0]) / duration)}
    if spec.kind == "jump":
        body_faces = body.part_faces("body")
        com = measures.centre_of_mass(V, body_faces)
        return {"height": measures.jump_height(com), "distance": measures.jump_distance(com)}
    if spec.kind == "reach":
        return {"height": measures.reach_height(V, body.hand_vertices("r"))}
    return {}


def studio_sequence_data(body, spec, *, fps, seed=0):
    """Consistent frames, ground truth and metadata of one sequence (no reconstruction yet).

    Returns
    -------
    data : dict with
        vertices : (frames, n, 3) float array   the true surface in the template's topology
                                                (metres, Y up: the truth frame)
        truth : dict of arrays (times, root_position, heading, joint_positions, joint_rotations,
                template_positions as float32), all in metres, Y up
        meta : dict (name, kind, fps, frames, duration, ..., units and axes of the files)
    """
    motion = studio_motion(body.skeleton, spec, fps=fps, seed=seed)
    V, positions = animate_studio(body, motion)
    root, heading = root_trajectory(motion)
    times = np.arange(len(V)) / fps
    meta = {
        "name": spec.name, "kind": spec.kind, "fps": fps, "frames": int(len(V)), "duration": float(len(V) / fps),
        "cyclic": False, "frames_per_cycle": None, "requested": dict(spec.params),
        "measured": _measured(body, spec, V, motion, root, heading),
        "motion_params": {"source": motion.source}, "events": {}, "seed": seed,
        **axes_record(spec.units, spec.up),
    }
    truth = {"times": times, "root_position": root, "heading": heading, "joint_positions": positions,
             "joint_rotations": motion.rotations, "template_positions": V.astype(np.float32)}
    return {"vertices": V, "truth": truth, "meta": meta}


def head_marks(body, truth):
    """Top of the head and its up direction per frame: (frames, 2, 3) (the cameras leave a hole there)."""
    sk = body.skeleton
    j = sk.index("head")
    R, P = truth["joint_rotations"][:, j], truth["joint_positions"][:, j]
    bone = sk.tails[j] - sk.rest[j]
    return np.stack([P + R @ (1.15 * bone), R @ bone], axis=1)


def reconstruct_frames(body, vertices, heads, camera, *, seed, frames=None, progress=None):
    """Reconstruct frames of a sequence as the studio does (see ``reconstruct.reconstruct_frame``).

    Parameters
    ----------
    body : StudioBody
    vertices : (frames, n, 3) float array   true surfaces (metres, Y up)
    heads : (frames, 2, 3) float array      ``head_marks``
    camera : StudioCamera
    seed : int        the sequence's seed; frame k uses seed * 100_003 + k
    frames : iterable of int or None   which frames (default all)
    progress : callable(done, total) or None

    Returns
    -------
    meshes : list of (V, F, colors) in metres, Y up
    stats : list of dict (per frame)
    """
    frames = range(len(vertices)) if frames is None else list(frames)
    thin = body.part[body.F[:, 0]] > 0
    meshes, stats = [], []
    for done, k in enumerate(frames, 1):
        V = np.asarray(vertices[k], dtype=np.float64)
        Vk, Fk, Ck, st = reconstruct_frame(V, body.F, body.colors, camera=camera, seed=seed * 100_003 + k, thin=thin,
                                           contact=contact_vertices(body.V, V), head_top=heads[k, 0],
                                           head_up=heads[k, 1])
        meshes.append((Vk, Fk, Ck))
        stats.append(st)
        if progress is not None:
            progress(done, len(frames))
    return meshes, stats


def generate_studio_sequence(body, spec, *, fps, camera, seed=0, progress=None):
    """Everything one studio sequence needs, in memory (``morphspace synth`` does the same in
    parallel chunks and writes the files).

    Returns
    -------
    data : dict with vertices, truth, meta (as ``studio_sequence_data``; meta also has
           unstructured_vertex_counts, noise_mm and the reconstruction summary under "studio")
           and unstructured: list of (V, F, colors), metres, Y up
    """
    data = studio_sequence_data(body, spec, fps=fps, seed=seed)
    meshes, stats = reconstruct_frames(body, data["vertices"], head_marks(body, data["truth"]), camera, seed=seed,
                                       progress=progress)
    data["meta"].update(unstructured_vertex_counts=[int(len(m[0])) for m in meshes], noise_mm=1000 * camera.noise,
                        studio=summarise_frames(stats))
    data["unstructured"] = meshes
    return data


def summarise_frames(stats):
    """Per-sequence summary of the reconstruction defects (for meta.json)."""
    def column(key):
        return np.array([s[key] for s in stats], dtype=float)

    return {
        "vertices": {"min": int(column("vertices").min()), "max": int(column("vertices").max()),
                     "mean": round(float(column("vertices").mean()), 1)},
        "frames_with_holes": int(np.sum(column("holes") > 0)),
        "holes_per_frame": round(float(column("holes").mean()), 2),
        "boundary_edges_per_frame": round(float(column("boundary_edges").mean()), 1),
        "fragments_per_frame": round(float(column("fragments").mean()), 2),
        "components_per_frame": round(float(column("components").mean()), 2),
        "bridged_vertices_per_frame": round(float(column("bridged").mean()), 1),
        "merged_vertices_per_frame": round(float(column("merged").mean()), 1),
        "frames_with_merges": int(np.sum(column("merged") > 0)),
        "noise_mm": round(1000 * float(stats[0]["noise_m"]), 3) if stats else None,
    }


__all__ = ["StudioSequenceSpec", "StudioCamera", "studio_motion", "animate_studio", "studio_sequence_data",
           "reconstruct_frames", "generate_studio_sequence", "summarise_frames", "head_marks", "LOOSE_GARMENT"]

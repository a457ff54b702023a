"""Building a motion space: sources on a common phase grid, decomposition, hybrid precompute.

``build_motion_space(path, clips, faces, ...)`` runs the offline chain of DESIGN.md steps 7-8 on
N consistent-topology clips and writes one ``.mspace`` file (``engine.motion_space.container``):

1. each clip is cut to one cycle (cyclic clips, from ``cycle_start``) or taken whole, expressed
   in its root frame (the horizontal drift of a cycle removed, so a cycle loops in place), and
   resampled to P phase samples by linear interpolation between frames;
2. the rest surface is tetrahedralised and embedded (``VolumetricEmbedding``);
3. every source frame on the grid is decomposed into rotations, stretches and local detail;
4. the hybrid references and sparse corrections are found by bisection to ``epsilon``.

Time-warping of key poses is not done here yet: sources are assumed to be aligned in phase
(equal-length synthetic cycles starting at the same key pose).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from engine.blend import (
    FrameDecomposer,
    LinearBlender,
    NonlinearBlender,
    PhasedNonlinearBlender,
    VolumetricEmbedding,
    build_hybrid,
    decompose_frames,
)
from engine.motion_space.container import write_container
from engine.surface import model_size

SPACE_FORMAT = "morphspace-motion-space"
SPACE_VERSION = 1


@dataclass
class SourceClip:
    """One source motion.

    Attributes
    ----------
    name : str
    vertices : (frames, n, 3) float array   consistent topology
    fps : float
    cyclic : bool
    frames_per_cycle : int or None          required for cyclic clips
    cycle_start : int                       first frame of the cycle used (cyclic clips)
    """

    name: str
    vertices: np.ndarray
    fps: float
    cyclic: bool
    frames_per_cycle: int | None = None
    cycle_start: int = 0

    def duration(self):
        """Seconds of the motion represented on the phase grid (one cycle, or the whole clip)."""
        if self.cyclic:
            return self.frames_per_cycle / self.fps
        return (len(self.vertices) - 1) / self.fps


def resample_clip(clip, n_phases):
    """Clip on the phase grid, in its root frame.

    Returns
    -------
    samples : (P, n, 3) float array
    velocity : (3,) float array   mean root velocity removed (m/s; zero for non-cyclic clips)
    """
    V = np.asarray(clip.vertices, dtype=np.float64)
    if clip.cyclic:
        N, s = int(clip.frames_per_cycle), int(clip.cycle_start)
        if N < 2 or s < 0 or s + N > len(V):
            raise ValueError(f"{clip.name}: a cycle of {N} frames from frame {s} needs {s + N} frames, "
                             f"the clip has {len(V)}")
        cycle = V[s:s + N + 1] if s + N < len(V) else None
        if cycle is None:  # the closing frame is not in the clip: the cycle repeats its first frame
            drift = np.zeros(3)
            cycle = np.concatenate([V[s:s + N], V[s:s + 1]])
        else:
            drift = cycle[-1].mean(axis=0) - cycle[0].mean(axis=0)
            drift[1] = 0.0
        local = cycle - (np.arange(N + 1) / N)[:, None, None] * drift
        x = np.arange(n_phases) / n_phases * N
        velocity = drift / (N / clip.fps)
    else:
        if len(V) < 2:
            raise ValueError(f"{clip.name}: a clip needs at least 2 frames, got {len(V)}")
        local = V
        x = np.linspace(0.0, len(V) - 1, n_phases)
        velocity = np.zeros(3)
    k0 = np.minimum(np.floor(x).astype(int), len(local) - 2)
    a = (x - k0)[:, None, None]
    return (1 - a) * local[k0] + a * local[k0 + 1], velocity


def build_motion_space(path, clips, faces, *, name, n_phases=None, epsilon=0.005, rest=None,
                       embedding=None, hybrid_options=None, progress=None):
    """Build and write a motion space.

    Parameters
    ----------
    path : path                   destination ``.mspace`` file (written atomically)
    clips : list of SourceClip    N >= 2 clips with the same topology, all cyclic or all not
    faces : (m, 3) int array
    name : str
    n_phases : int or None        phase samples P (default: the longest source's frame count)
    epsilon : float               hybrid error bound in metres (default 5 mm)
    rest : (n, 3) float array     rest surface to tetrahedralise (default: first source, phase 0)
    embedding : VolumetricEmbedding or None   reuse a cached tetrahedralisation of ``rest``
    hybrid_options : dict         extra options for ``build_hybrid``
    progress : callable(stage: str, done: int, total: int) or None

    Returns
    -------
    report : dict   what was built (sizes, timings, hybrid report)
    """
    report_progress = progress or (lambda stage, done, total: None)
    if len(clips) < 2:
        raise ValueError(f"a motion space needs at least 2 sources, got {len(clips)}")
    n = clips[0].vertices.shape[1]
    for clip in clips:
        if clip.vertices.ndim != 3 or clip.vertices.shape[1:] != (n, 3):
            raise ValueError(f"{clip.name}: vertices have shape {clip.vertices.shape}; every source "
                             f"needs (frames, {n}, 3) like {clips[0].name}")
    cyclic = {clip.cyclic for clip in clips}
    if len(cyclic) != 1:
        raise ValueError("sources must be all cyclic or all non-cyclic")
    cyclic = cyclic.pop()
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= n:
        raise ValueError(f"faces must be (m, 3) indices into {n} vertices")
    if n_phases is None:
        n_phases = max((c.frames_per_cycle if cyclic else len(c.vertices)) for c in clips)
    n_phases = int(n_phases)
    if n_phases < 2:
        raise ValueError(f"n_phases must be at least 2, got {n_phases}")
    timings = {}

    started = time.perf_counter()
    resampled = [resample_clip(c, n_phases) for c in clips]
    sources = np.stack([r[0] for r in resampled], axis=1)  # (P, N, n, 3)
    velocities = np.stack([r[1] for r in resampled])
    N = len(clips)
    report_progress("resample", 1, 1)

    rest = sources[0, 0] if rest is None else np.asarray(rest, dtype=np.float64)
    t0 = time.perf_counter()
    if embedding is None:
        report_progress("tetrahedralise", 0, 1)
        embedding = VolumetricEmbedding.from_surface(rest, faces)
    report_progress("tetrahedralise", 1, 1)
    timings["tetrahedralise_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    frames = sources.reshape(n_phases * N, n, 3)
    decomposer = FrameDecomposer(embedding)
    quaternions, stretch, detail = decompose_frames(
        decomposer, frames, progress=lambda d, t: report_progress("decompose", d, t))
    timings["decompose_s"] = time.perf_counter() - t0

    sources32 = np.ascontiguousarray(sources, dtype=np.float32)
    linear = LinearBlender(sources32, cyclic)
    nonlinear = PhasedNonlinearBlender(
        NonlinearBlender(embedding, quaternions, stretch, detail, sources32.reshape(n_phases * N, n, 3)),
        n_phases, N, cyclic)
    t0 = time.perf_counter()
    steps = [0]

    def hybrid_progress(message):
        steps[0] += 1
        report_progress("hybrid", steps[0], 0)

    tree, corrections, hybrid_report = build_hybrid(
        linear.blend_all_phases, nonlinear.blend_all_phases, N, n_phases, n, epsilon=epsilon,
        progress=hybrid_progress, **(hybrid_options or {}))
    timings["hybrid_s"] = time.perf_counter() - t0

    size = model_size(rest)
    lo = sources.reshape(-1, 3).min(axis=0)
    hi = sources.reshape(-1, 3).max(axis=0)
    metadata = {
        "format": SPACE_FORMAT, "version": SPACE_VERSION, "name": name, "cyclic": cyclic,
        "n_sources": N, "n_phases": n_phases, "n_vertices": int(n), "n_faces": int(len(faces)),
        "n_tet_vertices": int(len(embedding.V_tet)), "n_tets": int(len(embedding.T)),
        "model_size": size, "epsilon": float(epsilon), "units": "m", "up": "+Y", "forward": "+Z",
        "bounds": [lo.tolist(), hi.tolist()],
        "sources": [{"name": c.name, "duration": c.duration(), "fps": c.fps, "frames": int(len(c.vertices)),
                     "cyclic": c.cyclic, "root_velocity": velocities[i].tolist()}
                    for i, c in enumerate(clips)],
        "hybrid": {"references": hybrid_report.references, "leaves": hybrid_report.leaves,
                   "max_depth": hybrid_report.max_depth, "max_test_error": hybrid_report.max_test_error,
                   "nonlinear_evaluations": hybrid_report.nonlinear_evaluations,
                   "stored_fraction": hybrid_report.stored_fraction,
                   "correction_bytes": int(corrections.nbytes()), "source_bytes": int(sources32.nbytes)},
        "timings": {k: round(v, 3) for k, v in timings.items()},
    }
    arrays = {
        "faces": faces.astype(np.int32), "sources": sources32, "rest": rest,
        "root_velocity": velocities.astype(np.float64),
        "tet_vertices": embedding.V_tet, "tets": embedding.T.astype(np.int32),
        "surface_tet": embedding.surface_tet.astype(np.int32), "surface_bary": embedding.surface_bary,
        "nl_quaternions": quaternions, "nl_stretch": stretch, "nl_detail": detail,
        "hybrid_references": tree.references, "hybrid_cells": tree.cells.astype(np.int32),
        "hybrid_children": tree.children.astype(np.int32), "hybrid_split": tree.split.astype(np.int32),
        "corrections_pointer": corrections.pointer, "corrections_vertex": corrections.vertex,
        "corrections_value": corrections.value, "corrections_scale": corrections.scale,
    }
    timings["total_s"] = time.perf_counter() - started
    metadata["timings"]["total_s"] = round(timings["total_s"], 3)
    write_container(path, arrays, metadata)
    return {"path": str(path), **metadata}

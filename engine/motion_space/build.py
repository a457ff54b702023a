"""Building a motion space: root motion, time-warp, decomposition, hybrid precompute.

``build_motion_space(path, clips, faces, ...)`` runs the offline chain of DESIGN.md steps 5-8 on
N consistent-topology clips and writes one ``.mspace`` file (``engine.motion_space.container``):

1. every clip is split into root motion and root-local meshes (``engine.root_motion``);
2. the clips are time-warped onto a common phase grid of P samples (``prepare_sources``):
   cyclic clips are cut to one cycle and their key poses aligned to the first source's by
   circular shift and DTW; one-shot clips are warped piecewise linearly between key events
   (take-off and landing, or the peak); each keeps its real duration, and its root velocity
   and turn rate are stored per phase for the player;
3. the rest surface is tetrahedralised and embedded (``VolumetricEmbedding``);
4. every source frame on the grid is decomposed into rotations, stretches and local detail;
5. the hybrid references and sparse corrections are found by bisection to ``epsilon``.
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
from engine.blend import HybridBlender, phase_of_sample
from engine.motion_space.container import write_container
from engine.parameters import ParameterMap, RootTrack, measure_parameters
from engine.parameters.sheet import between_weights, sheet_weights
from engine.motion_space.roots import cyclic_root, source_roots
from engine.root_motion import travel_turn, turned_reference
from engine.surface import model_size
from engine.timewarp import (
    align_cycle,
    cycle_at,
    piecewise_warp,
    refine_offset,
    sample_frames,
)

SPACE_FORMAT = "morphspace-motion-space"
SPACE_VERSION = 4  # 2: root-local time-warped sources, root rates, int8 hierarchical corrections;
                   # 3: correction rows' vertex sets as index lists or bitmasks (corrections_mask);
                   # 4: a conforming bisection tree (no reference on a leaf's edge; a version 3 tree
                   #    could hang one, and its hybrid was off by up to 269 mm there) and every
                   #    reference kept within the bound by pruning


@dataclass
class SourceClip:
    """One source motion.

    Attributes
    ----------
    name : str
    vertices : (frames, n, 3) float array   consistent topology, world coordinates
    fps : float
    cyclic : bool
    frames_per_cycle : float or None        cycle length hint; estimated when None
    """

    name: str
    vertices: np.ndarray
    fps: float
    cyclic: bool
    frames_per_cycle: float | None = None


@dataclass
class PreparedSources:
    """Sources on the common phase grid (the output of ``prepare_sources``).

    Attributes
    ----------
    samples : (P, N, n, 3) float array   root-local frames at every phase sample
    times : (P, N) float array           source frame time used for each sample
    durations : (N,) float array         seconds of each source's cycle (or clip)
    root_rate : (P, N, 3) float array    root displacement per unit phase, in the root frame (m)
    turn_rate : (P, N) float array       heading change per unit phase (rad)
    info : list of dict                  per source: period, events, warp
    heading_turn : float                 radians the heading reference was turned from the rest's
                                         facing to the sources' travel (``travel_turn``; 0: not)
    """

    samples: np.ndarray
    times: np.ndarray
    durations: np.ndarray
    root_rate: np.ndarray
    turn_rate: np.ndarray
    info: list
    heading_turn: float = 0.0


def _align_to(reference, local, start, period, n_phases):
    """Warp (in cycle samples) of the cycle of ``local`` starting at ``start`` onto ``reference``:
    DTW on the sampled cycle, then a sub-sample offset fitted on the frames themselves."""
    warp = align_cycle(reference, cycle_at(local, start, period, n_phases))

    def sampler(positions):
        return sample_frames(local, start + np.mod(positions * period / n_phases, period))

    return refine_offset(reference, sampler, warp)


def _root_rates(root, times, span_frames):
    """Root displacement and heading change per unit phase at source frame ``times``.

    ``span_frames`` is how many source frames one unit of phase covers locally: the velocity
    (per second) times the seconds per unit phase.
    """
    velocity = sample_frames(root.velocity(), times)
    turn = sample_frames(root.turn_rate()[:, None], times)[:, 0]
    seconds = span_frames / root.fps
    return velocity * seconds[:, None], turn * seconds


def prepare_sources(clips, faces, rest, n_phases=None, heading_turn=None):
    """Root motion and time-warp of every clip onto a common phase grid (steps 5-6).

    ``n_phases`` defaults to the longest cycle (cyclic clips) or clip, in frames. ``heading_turn``
    (radians) turns the heading reference from the rest's facing; None: the sources' own travel
    (``travel_turn``). An aligned capture gives its whole capture's (``capture_travel_turn``),
    so every space built from it shares one heading 0.
    """
    size = model_size(rest)
    cyclic = clips[0].cyclic
    roots, info = source_roots(clips, faces, rest, size, cyclic)
    # heading 0 is where the sources travel, not where a captured rest faces
    turn = travel_turn(roots, size) if heading_turn is None else float(heading_turn)
    if turn:
        roots, info = source_roots(clips, faces, turned_reference(rest, turn), size, cyclic)

    if n_phases is None:
        n_phases = max(int(round(e["period_frames"])) for e in info) if cyclic else max(len(c.vertices) for c in clips)
    P = int(n_phases)
    if P < 2:
        raise ValueError(f"n_phases must be at least 2, got {P}")
    N = len(clips)
    samples = np.empty((P, N) + clips[0].vertices.shape[1:])
    times = np.empty((P, N))
    root_rate = np.empty((P, N, 3))
    turn_rate = np.empty((P, N))
    durations = np.empty(N)
    if cyclic:
        reference = None
        for i, (clip, root) in enumerate(zip(clips, roots)):
            period = info[i]["period_frames"]
            start = 0.5 * (len(clip.vertices) - 1 - period)  # the middle cycle: farthest from the ends
            cycle = cycle_at(root.local, start, period, P)
            if reference is None:
                reference, warp = cycle, np.arange(P, dtype=float)
            else:
                warp = _align_to(reference, root.local, start, period, P)
            t = start + np.mod(warp * period / P, period)
            samples[:, i] = sample_frames(root.local, t)
            times[:, i] = t
            slope = np.gradient(np.concatenate([warp, [warp[0] + P]]))[:P] * period / P  # frames per sample
            root_rate[:, i], turn_rate[:, i] = _root_rates(root, t, slope * P)
            durations[i] = period / clip.fps
            info[i]["cycle_start_frame"] = float(start + np.mod(warp[0] * period / P, period))
    else:
        kinds = {entry["events_kind"] for entry in info}
        counts = {len(entry["events_frames"]) for entry in info}
        phases = np.linspace(0.0, 1.0, P)
        if len(kinds) == 1 and len(counts) == 1:
            normalised = np.array([np.asarray(e["events_frames"]) / (len(c.vertices) - 1) for e, c in zip(info, clips)])
            common = normalised.mean(axis=0)
        else:  # sources disagree on their events: warp uniformly
            common = None
        for i, (clip, root) in enumerate(zip(clips, roots)):
            frames = len(clip.vertices)
            if common is None:
                t = phases * (frames - 1)
            else:
                t = piecewise_warp(info[i]["events_frames"], frames, common)(phases)
            samples[:, i] = sample_frames(root.local, t)
            times[:, i] = t
            slope = np.gradient(t, phases)  # frames per unit phase
            root_rate[:, i], turn_rate[:, i] = _root_rates(root, t, slope)
            durations[i] = (frames - 1) / clip.fps
            info[i]["common_event_phases"] = None if common is None else [float(c) for c in common]
    return PreparedSources(samples=samples, times=times, durations=durations, root_rate=root_rate,
                           turn_rate=turn_rate, info=info, heading_turn=turn)


def warp_cycle_onto(clip, faces, rest, reference):
    """A cyclic clip put on an existing space's phase grid, exactly as its sources were.

    Parameters
    ----------
    clip : SourceClip              cyclic
    faces : (m, 3) int array
    rest : (n, 3) float array      the space's rest surface (heading reference)
    reference : (P, n, 3) array    the space's first source on its grid (``space.sources[:, 0]``)

    Returns
    -------
    samples : (P, n, 3) float array   root-local, key poses aligned to the reference
    """
    P = len(reference)
    root, period = cyclic_root(clip, faces, rest)
    start = 0.5 * (len(clip.vertices) - 1 - period)
    warp = _align_to(np.asarray(reference, dtype=np.float64), root.local, start, period, P)
    return sample_frames(root.local, start + np.mod(warp * period / P, period))


def effector_vertices(samples, fraction=0.015):
    """Vertices that move most in the sources (a reach's hand): the top ``fraction`` by their
    largest displacement from the first phase sample, over all sources."""
    displacement = np.linalg.norm(samples - samples[:1], axis=3).max(axis=(0, 1))
    count = max(1, int(round(fraction * samples.shape[2])))
    return np.sort(np.argsort(displacement)[-count:]).astype(np.int32)


# Metadata keys build_motion_space writes itself (``metadata=`` may not set them).
BUILT_METADATA = ("format", "version", "name", "cyclic", "n_sources", "n_phases", "n_vertices", "n_faces",
                  "n_tet_vertices", "n_tets", "model_size", "epsilon", "units", "up", "forward", "bounds",
                  "heading_turn_deg",
                  "sources", "hybrid", "timings", "parameters")


def build_motion_space(path, clips, faces, *, name, n_phases=None, epsilon=0.005, rest=None,
                       embedding=None, hybrid_options=None, parameters=None, metadata=None, progress=None,
                       runner=None, heading_turn=None):
    """Build and write a motion space.

    Parameters
    ----------
    path : path                   destination ``.mspace`` file (written atomically)
    clips : list of SourceClip    N >= 2 clips with the same topology, all cyclic or all not
    faces : (m, 3) int array
    name : str
    n_phases : int or None        phase samples P (default: the longest source's cycle or clip)
    epsilon : float               hybrid error bound in metres (default 5 mm)
    rest : (n, 3) float array     rest surface: tetrahedralised, and its facing is heading 0 of
                                  every source (default: the first source's first frame)
    embedding : VolumetricEmbedding or None   reuse a cached tetrahedralisation of ``rest``
    hybrid_options : dict         extra options for ``build_hybrid``
    parameters : dict or None     high-level parameters: ``layout`` (engine.parameters.Layout),
                                  ``names`` (measures, e.g. ["speed", "turn_rate"]), optional
                                  ``resolution`` (samples per axis)
    metadata : dict or None       more JSON metadata for the space, e.g. what the sources were in
                                  before they were converted to metres, +Y up (``source_units``,
                                  ``source_up``, ``input``: see ``server.units.source_metadata``);
                                  the keys the builder writes itself (``BUILT_METADATA``) are refused
    progress : callable(stage: str, done: int, total: int) or None
    runner : task runner or None  decomposes chunks of source frames as its tasks (engine.tasks)
    heading_turn : float or None  radians from the rest's facing to heading 0 (``prepare_sources``;
                                  None: where the sources travel)

    Returns
    -------
    report : dict   what was built: the file's metadata, its ``path``, and ``timings`` (seconds
                    per stage; not in the file, which holds only what the input decides, so the
                    same input gives the same bytes)
    """
    report_progress = progress or (lambda stage, done, total: None)
    extra = dict(metadata or {})
    clash = sorted(set(extra) & set(BUILT_METADATA))
    if clash:
        raise ValueError(f"metadata {', '.join(clash)}: the builder writes these itself")
    if len(clips) < 2:
        raise ValueError(f"a motion space needs at least 2 sources, got {len(clips)}")
    n = clips[0].vertices.shape[1]
    for clip in clips:
        if clip.vertices.ndim != 3 or clip.vertices.shape[1:] != (n, 3):
            raise ValueError(f"{clip.name}: vertices have shape {clip.vertices.shape}; every source "
                             f"needs (frames, {n}, 3) like {clips[0].name}")
    cyclic = {clip.cyclic for clip in clips}
    if len(cyclic) != 1:
        loops = [clip.name for clip in clips if clip.cyclic]
        once = [clip.name for clip in clips if not clip.cyclic]
        raise ValueError(f"sources must be all cyclic or all non-cyclic: {', '.join(loops)} cyclic, "
                         f"{', '.join(once)} not (meta.json's cyclic, or --cyclic for sources without one)")
    cyclic = cyclic.pop()
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= n:
        raise ValueError(f"faces must be (m, 3) indices into {n} vertices")
    timings = {}

    started = time.perf_counter()
    rest = np.asarray(clips[0].vertices[0] if rest is None else rest, dtype=np.float64)
    if rest.shape != (n, 3):
        raise ValueError(f"rest must have shape ({n}, 3), got {rest.shape}")
    report_progress("time-warp", 0, 1)
    prepared = prepare_sources(clips, faces, rest, n_phases, heading_turn)
    sources = prepared.samples  # (P, N, n, 3), root-local
    n_phases = sources.shape[0]
    N = len(clips)
    report_progress("time-warp", 1, 1)
    timings["timewarp_s"] = time.perf_counter() - started

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
        decomposer, frames, progress=lambda d, t: report_progress("decompose", d, t), runner=runner)
    timings["decompose_s"] = time.perf_counter() - t0

    sources32 = np.ascontiguousarray(sources, dtype=np.float32)
    linear = LinearBlender(sources32, cyclic)
    nonlinear = PhasedNonlinearBlender(
        NonlinearBlender(embedding, quaternions, stretch, detail, sources32.reshape(n_phases * N, n, 3)),
        n_phases, N, cyclic)
    t0 = time.perf_counter()

    def hybrid_progress(message, done, total):
        report_progress("hybrid", done, total)

    options = dict(hybrid_options or {})
    if parameters is not None and "test_weights" not in options:
        options["test_weights"] = sheet_weights(parameters["layout"])
        options.setdefault("check_weights", between_weights(parameters["layout"]))
    tree, corrections, hybrid_report = build_hybrid(
        linear.blend_all_phases, nonlinear.blend_all_phases, N, n_phases, n, epsilon=epsilon,
        progress=hybrid_progress, **options)
    timings["hybrid_s"] = time.perf_counter() - t0

    effector = effector_vertices(sources)
    track = RootTrack(durations=prepared.durations, root_rate=prepared.root_rate, turn_rate=prepared.turn_rate,
                      cyclic=cyclic)
    parameter_map = None
    if parameters is not None:
        t0 = time.perf_counter()
        hybrid = HybridBlender(sources32, tree, corrections, cyclic)

        def blend_phases(w):
            return np.stack([hybrid.blend(w, phase_of_sample(p, n_phases, cyclic)) for p in range(n_phases)])

        names = list(parameters["names"])
        parameter_map = ParameterMap.sample(
            parameters["layout"], names,
            lambda w: measure_parameters(names, w, track, blend_phases, faces=faces, effector=effector),
            resolution=parameters.get("resolution"),
            progress=lambda d, t: report_progress("parameters", d, t))
        timings["parameters_s"] = time.perf_counter() - t0

    size = model_size(rest)
    lo = sources.reshape(-1, 3).min(axis=0)
    hi = sources.reshape(-1, 3).max(axis=0)
    metadata = {
        "format": SPACE_FORMAT, "version": SPACE_VERSION, "name": name, "cyclic": cyclic,
        "n_sources": N, "n_phases": n_phases, "n_vertices": int(n), "n_faces": int(len(faces)),
        "n_tet_vertices": int(len(embedding.V_tet)), "n_tets": int(len(embedding.T)),
        "model_size": size, "epsilon": float(epsilon), "units": "m", "up": "+Y", "forward": "+Z",
        "heading_turn_deg": round(float(np.degrees(prepared.heading_turn)), 6),
        "bounds": [lo.tolist(), hi.tolist()],
        "sources": [{"name": c.name, "duration": float(prepared.durations[i]), "fps": c.fps,
                     "frames": int(len(c.vertices)), "cyclic": c.cyclic, **prepared.info[i]}
                    for i, c in enumerate(clips)],
        "hybrid": {"references": hybrid_report.references, "leaves": hybrid_report.leaves,
                   "max_depth": hybrid_report.max_depth, "max_test_error": hybrid_report.max_test_error,
                   "check_points": hybrid_report.check_points,
                   "max_check_error": hybrid_report.max_check_error if hybrid_report.check_points else None,
                   "check_added": hybrid_report.check_added,
                   "nonlinear_evaluations": hybrid_report.nonlinear_evaluations,
                   "stored_fraction": hybrid_report.stored_fraction,
                   "correction_bytes": int(corrections.nbytes()), "source_bytes": int(sources32.nbytes)},
        "parameters": None if parameter_map is None else parameter_map.to_metadata(),
        **extra,
    }
    arrays = {
        "faces": faces.astype(np.int32), "sources": sources32, "rest": rest,
        "durations": prepared.durations, "root_rate": prepared.root_rate, "turn_rate": prepared.turn_rate,
        "warp_times": prepared.times, "effector": effector,
        "tet_vertices": embedding.V_tet, "tets": embedding.T.astype(np.int32),
        "surface_tet": embedding.surface_tet.astype(np.int32), "surface_bary": embedding.surface_bary,
        "nl_quaternions": quaternions, "nl_stretch": stretch, "nl_detail": detail,
        "hybrid_references": tree.references, "hybrid_cells": tree.cells.astype(np.int32),
        "hybrid_children": tree.children.astype(np.int32), "hybrid_split": tree.split.astype(np.int32),
    }
    arrays.update({f"corrections_{key}": value for key, value in corrections.to_arrays().items()})
    if parameter_map is not None:
        arrays.update(parameter_map.to_arrays())
    write_container(path, arrays, metadata)  # no timings in it: the same input gives the same bytes
    timings["total_s"] = time.perf_counter() - started
    return {"path": str(path), **metadata, "timings": {k: round(v, 3) for k, v in timings.items()}}

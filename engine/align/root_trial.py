"""Choosing the root by trying it: the candidate that aligns a few sample frames best.

Every frame is the root's mesh deformed, so a merged contact in the root (a sleeve against the
skirt, a hand on the hip) is tied into every aligned frame, and where the frames pull it apart
the alignment tears elsewhere (:mod:`engine.align.root_choice`). The geodesic spread that
:func:`engine.align.root_choice.choose_root` reads does not always see such a contact: on the
studio's martial-arts take, sampled one frame in 9, posing moved the spread more than the
sleeves merged with the skirt did, and the most central frame (both bell sleeves merged with
the skirt) stayed the root, 3.30% of the model size mean error. Rooted at a frame four places
down the centrality order whose sleeves hang free, the same run erred 1.93%.

So the root is tried: a few candidates (the frame the spread chose, then the most central others,
each unlike those already taken) each align the same few probe frames, spread evenly over the
capture, straight from themselves; the candidate whose probes come out with the least badness
(:func:`engine.align.repair.alignment_badness` against no capture floor: the fit, the tail of
the solid's distortion and, with colour cues, the colours' disagreement) is the root. A root
with a merged contact shows it in every probe whose limbs are apart: the solid tears there. It
is a noisy judge: on that take it took frame 9 (2.96%) over the spread's 378 (3.22%), not the
best of its four candidates (27, 1.89%), and on the dance sampled one frame in 14 frame 0
(7.70%, the best of its four) over the spread's 406 (9.19%); more candidates and probes ranked worse, a punch that
aligns the punch probes winning (docs/evaluation.md, "The root tried").

The trial costs ``TRIAL_CANDIDATES`` set-ups and ``TRIAL_CANDIDATES * TRIAL_PROBES`` pairwise
alignments, a fixed amount whatever the capture's length, and is skipped for captures shorter
than ``TRIAL_MIN_FRAMES``. It runs as runner tasks (one per candidate), so a cluster tries the
candidates at the same time; the result does not depend on where they run.
"""

from __future__ import annotations

import numpy as np

TRIAL_CANDIDATES = 4    # candidate roots tried
TRIAL_PROBES = 6        # frames each candidate aligns
TRIAL_MIN_FRAMES = 24   # fewer frames than this: no trial, the spread's choice stands
TRIAL_APART = 0.5       # a candidate is at least this share of the median dissimilarity from those taken


def trial_candidates(dissimilarity, centrality, first, *, slack, count=TRIAL_CANDIDATES, apart=TRIAL_APART,
                     allowed=None):
    """The candidate roots: ``first`` (the spread's choice), then the most central frames within
    ``slack`` of the most central, skipping frames closer than ``apart`` times the median
    dissimilarity to a candidate already taken (the rest poses at a take's start and end are one
    pose). When ``allowed`` (frame indices: those :func:`engine.align.root_choice.choose_root`
    allowed by their handles) is given, those frames come first and the others only fill the
    places they leave (a merged sleeve closes no handle when it is merged all along: on the whole
    studio the one frame the handles allowed erred 2.95% mean as the root, the race among the
    filled candidates 2.13%).
    Fewer than ``count`` when the close ones are all that is left.

    Returns a list of frame indices, ``first`` first.
    """
    D = np.asarray(dissimilarity, dtype=np.float64)
    centrality = np.asarray(centrality, dtype=np.float64)
    order = np.argsort(centrality, kind="stable")
    best = max(float(centrality[order[0]]), 1e-300)
    pool = [int(f) for f in order if centrality[f] <= (1.0 + float(slack)) * best]
    if allowed is not None:
        allowed = {int(f) for f in allowed}
        pool = [f for f in pool if f in allowed] + [f for f in pool if f not in allowed]
    off = D[~np.eye(len(D), dtype=bool)]
    near = float(apart) * (float(np.median(off)) if len(off) else 0.0)
    taken = [int(first)]
    for frame in pool:
        if len(taken) >= count:
            break
        if frame not in taken and np.min(D[frame, taken]) >= near:
            taken.append(frame)
    return taken


def trial_probes(n, candidates, count=TRIAL_PROBES):
    """``count`` probe frames spread evenly over ``n`` frames, none of them a candidate (a
    candidate's own frame would align perfectly from itself): the frame at the middle of each
    of ``count`` equal stretches, or the nearest frame to it that is neither a candidate nor
    taken already."""
    blocked = set(int(c) for c in candidates)
    probes = []
    for k in range(int(count)):
        centre = int((k + 0.5) * n / count)
        for step in range(n):
            picked = next((f for f in (centre - step, centre + step)
                           if 0 <= f < n and f not in blocked and f not in probes), None)
            if picked is not None:
                probes.append(picked)
                break
    return probes


def root_setup(mesh, options, use_colors, colours, seed, tets=None, label=None):
    """The pairwise aligner of a root frame, as :func:`engine.align.align_captures` sets it up.

    Parameters
    ----------
    mesh : Mesh-like                the root frame
    options : AlignmentOptions
    use_colors : bool or "auto"     see :func:`engine.align.align_captures`
    colours : bool                  every frame has vertex colours
    seed : int
    tets : (V_tet, T) or None       the root's tet mesh (default: tetrahedralised here)
    label : str or None             names the frame in an error (default: its ``source``)

    Returns
    -------
    aligner : PairwiseAligner
    options : AlignmentOptions      with the colour weight the cues need
    cues : bool                     colour cues are on
    kept : (n,) int array           the root's vertices kept (its main pieces)
    """
    from dataclasses import replace

    from engine.align.captures import COLOUR_WEIGHT, colours_carry_texture
    from engine.align.pairwise import PairwiseAligner
    from engine.surface import main_components
    from engine.tetmesh import tetrahedralize

    # the root's floating fragments would become part of every aligned frame: leave them out
    V, F, kept = main_components(mesh.vertices, mesh.faces)
    cues = colours and (use_colors is True or (use_colors == "auto" and colours_carry_texture(V, F)))
    if cues and not options.colour_weight:
        options = replace(options, colour_weight=COLOUR_WEIGHT)
    elif not cues and options.colour_weight:
        options = replace(options, colour_weight=0.0)
    C = np.asarray(mesh.colors)[kept] if colours else None
    if tets is None:
        try:
            tets = tetrahedralize(V, F, resolution=options.tet_resolution)
        except ValueError as exc:
            label = label or getattr(mesh, "source", None) or "the root frame"
            raise ValueError(f"{label}: the root frame cannot be filled with tetrahedra: {exc}; align from "
                             "another root (morphspace align --root SEQUENCE:FRAME)") from None
    return PairwiseAligner(V, F, C, tets=tets, options=options, seed=seed), options, bool(cues), kept


def trial_task(shared, job):
    """Runner task: one candidate root aligns the probes (``shared``: their (V, F, colors)).

    ``job``: (candidate mesh as (V, F, colors, source), options, use_colors, colours, seed, yaw
    hints per probe). Returns {"badness": per probe, "tets": the candidate's tet mesh} (a frame
    that cannot be filled with tetrahedra gets infinite badness)."""
    from types import SimpleNamespace

    from engine.align.matching import TargetSurface
    from engine.align.repair import alignment_badness
    from engine.surface import model_size
    from engine.tasks import checkpoint, shared_value

    (V, F, C, source), options, use_colors, colours, seed, hints = job
    probes = shared_value(shared)
    try:
        aligner, _, cues, _ = root_setup(SimpleNamespace(vertices=V, faces=F, colors=C, source=source), options, use_colors, colours, seed)
    except ValueError:
        return {"badness": np.full(len(probes), np.inf), "tets": None}
    rows = []
    for (PV, PF, PC), hint in zip(probes, hints, strict=True):
        checkpoint()
        result = aligner.align(aligner.V_tet, TargetSurface(PV, PF, PC if cues else None), yaw=hint)
        rows.append((result.residual, result.distortion_tail, result.colour_distance))
    rows = np.array(rows, dtype=np.float64).reshape(-1, 3)
    floor = aligner.colour_floor if cues else None
    badness = alignment_badness(rows[:, 0], rows[:, 1], model_size(aligner.V), 0.0,
                                rows[:, 2] if cues else None, floor)
    return {"badness": np.asarray(badness, dtype=np.float64), "tets": (aligner.V_tet, aligner.T)}


def try_roots(meshes, candidates, probes, yaw, *, options, use_colors, colours, seed=0, runner=None,
              workers=1, progress=None):
    """Align ``probes`` from every candidate root; the candidate with the least mean badness.

    Parameters
    ----------
    meshes : list of Mesh-like      all frames
    candidates, probes : lists of frame indices (:func:`trial_candidates`, :func:`trial_probes`)
    yaw : (N, N) array or None      the similarity's yaw (degrees turning frame j onto frame i)
    options, use_colors, colours, seed : as :func:`root_setup`
    runner : task runner or None    runs the candidates as tasks (default: here, or ``workers``
                                    processes)
    progress : callable(done, total) or None

    Returns
    -------
    root : int
    report : dict   ``candidates``, ``probes``, ``badness`` (candidates x probes), ``mean`` (None for a
                    candidate that could not be filled with tetrahedra)
    tets : dict     candidate -> its tet mesh (V_tet, T), None where it could not be filled
    """
    from engine.align.propagation import mesh_arrays
    from engine.tasks import ProcessRunner

    shared = [mesh_arrays(meshes[p], colours) for p in probes]
    jobs = []
    for c in candidates:
        V, F, C = mesh_arrays(meshes[c], colours)
        hints = [None if yaw is None else float(yaw[p, c]) for p in probes]
        jobs.append(((V, F, C, getattr(meshes[c], "source", None)), options, use_colors, colours, seed, hints))
    if progress is not None:
        progress(0, len(jobs))  # the stage starts now (a candidate's set-up and probes take a while)
    if runner is not None:
        outs = runner.map(trial_task, jobs, shared=shared, progress=progress)
    else:
        with ProcessRunner(workers) as local:   # one worker: here
            outs = local.map(trial_task, jobs, shared=shared, progress=progress)
    badness = np.stack([out["badness"] for out in outs])
    mean = badness.mean(axis=1)
    best = int(np.argmin(mean))  # the first of equals: the spread's choice wins a tie
    # a candidate that could not be filled with tetrahedra has no badness: null in the report
    # (strict JSON: the job record and the aligned dataset's manifest carry it)
    report = {"candidates": [int(c) for c in candidates], "probes": [int(p) for p in probes],
              "badness": [_finite(row) for row in badness], "mean": _finite(mean)}
    return int(candidates[best]), report, {int(c): out["tets"] for c, out in zip(candidates, outs)}


def _finite(values):
    """``values`` rounded to 4 places as a list, None where not finite."""
    return [round(float(v), 4) if np.isfinite(v) else None for v in values]


__all__ = ["TRIAL_CANDIDATES", "TRIAL_MIN_FRAMES", "TRIAL_PROBES", "root_setup", "trial_candidates",
           "trial_probes", "trial_task", "try_roots"]

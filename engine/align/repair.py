"""Finding and repairing frames whose correspondence slipped (limb swaps and slides).

Along a long tree path small errors add up until a whole limb sits on its neighbour's place,
while the surface fit stays small: the fit alone cannot see it. The aligned solid can: the tets
of the root that carried the limb are torn where it slid (a hip, a shoulder). So every frame
gets a confidence from its fit *and* the tail of its distortion (the worst 5% of the solid,
``PairAlignment.distortion_tail``) beyond the capture's own floor: loose garments (a skirt, wide
sleeves) deform that much in every frame, so the tail the frames aligned straight from the root
show (:func:`tail_reference`) is subtracted first. Where the frames carry vertex colours, the
confidence also reads the colours where each frame's vertices landed against the root's
(:mod:`engine.align.appearance`): anchored to the root, they show what a frame inherited along
its path as well as its own step's slip. With colour cues on, the tail then counts only where the
solid is torn far beyond the floor; with them off, the colours add to the tail. Frames below a
confidence of one half are aligned again from
other sources: first from the root itself (a frame aligned straight from the root cannot
inherit a slip; the frames most like the root first, as far as the budget goes), then, where
that did not lift the frame to one half, parents first from the most similar trusted frames;
the best result by the same score is kept (with ``AlignmentOptions.graft_limbs``, between the two:
a frame the root left flagged has its limbs grafted from the other frames' poses and is aligned
again, :mod:`engine.align.limb_graft`). A frame that no source aligns well stays flagged,
with its confidence, never silent.
"""

from __future__ import annotations

import numpy as np

from engine.align.matching import TargetSurface
from engine.align.repair_waves import SerialRunner, forward_only, repair_task, run_phase

TAIL_SCALE = 4.0       # distortion tail (||F - R||^2 over the worst 5% of the solid) at confidence 1/e ...
TAIL_RELATIVE = 0.0    # ... plus this share of the capture's floor; 0.25 halved the dance's false flags
                       # but missed 3 of 8 frames over 3% on studio-tiny (docs/alignment.md), so it is off
TAIL_FLOOR = 20.0      # ... but at most this many times the floor: a body whose own frames hardly deform
                       # (a tight suit, a coarse mesh) shows a leg on the other leg's place by a tail far
                       # below TAIL_SCALE (the tiny run: floor 0.05, swapped legs 0.7-1.0, docs/alignment.md)
TAIL_LEAST = 0.25      # ... and never below this
RESIDUAL_SCALE = 0.01  # mean two-sided fit residual, as a fraction of the model size, at 1/e
COLOUR_FREE = 1.3      # colour disagreement (in units of the root's own floor) that costs nothing ...
COLOUR_SCALE = 0.58    # ... and the excess over it at confidence 1/e (1.7 times the floor: confidence 1/2)
TAIL_WITH_COLOUR = 2.0 # with colours, the distortion tail (in its units) that costs nothing
TRUSTED = 0.5          # frames at or above this confidence are trusted sources and left alone
COLOUR_MARGIN = 0.1    # with colours, results whose colours agree within this share of the best compete
TURN_COLOUR = 2.5      # a flagged frame is also aligned turned round when its colours disagree this many
                       # times more than the trusted frames' do (median): a body facing the wrong way
TURN_SAMPLE = 16       # trusted frames whose colours set that median (evenly spaced in the tree's order)
GRAFT = -2             # a source that stands for the frame's own alignment with limbs grafted (engine.align.limb_graft)
YIELD_CHUNK = 32       # a phase's frames go out in runs of about this many alignments ...
MIN_YIELD = 1.0 / 16.0 # ... and a run that mends fewer frames than this share of its alignments ends the phase
                       # (the whole studio: 1 frame mended in 455 alignments from the root, 29 minutes;
                       # the dance alone: 45 in 77; docs/evaluation.md, "A repair that stops when it stops paying")


def alignment_badness(residual, distortion_tail, model_size, reference=0.0, colour=None, colour_floor=None,
                      tail_free=TAIL_WITH_COLOUR):
    """Badness of aligned frames: fit residual and the distortion tail beyond ``reference``
    (:func:`tail_reference`), each in units of its scale (the tail's: :func:`tail_scale`).

    With ``colour`` (the frames' colour disagreement,
    :func:`engine.align.appearance.colour_disagreement`) and the root's ``colour_floor``: plus how
    far the disagreement exceeds ``COLOUR_FREE`` times the floor, in units of ``COLOUR_SCALE``
    times the floor, and the tail counts only beyond ``tail_free`` of its units (``TAIL_WITH_COLOUR``:
    a solid torn that much, as a limb on its neighbour's place tears it, whatever the colours say;
    below that the colours see a slip better than the tail). With colour cues off (colours too
    coarse to guide the matching, :func:`colour_terms`) ``tail_free`` is 0: the colours add to the
    tail and do not excuse it. NaN colours add nothing.
    """
    excess = np.maximum(np.asarray(distortion_tail, dtype=np.float64) - float(reference), 0.0)
    tail = excess / tail_scale(reference)
    residual = np.asarray(residual, dtype=np.float64) / (RESIDUAL_SCALE * float(model_size))
    if colour is None or colour_floor is None or not np.isfinite(colour_floor) or colour_floor <= 0:
        return tail + residual
    ratio = np.asarray(colour, dtype=np.float64) / float(colour_floor)
    seen = np.nan_to_num(np.maximum(ratio - COLOUR_FREE, 0.0) / COLOUR_SCALE)
    return residual + seen + np.where(np.isfinite(ratio), np.maximum(tail - tail_free, 0.0), tail)


def tail_scale(reference):
    """The distortion tail beyond the floor that costs one unit of badness: ``TAIL_SCALE`` (plus
    ``TAIL_RELATIVE`` times the floor), but at most ``TAIL_FLOOR`` times a known floor (``reference``
    > 0) and at least ``TAIL_LEAST``. A tail twenty times what the capture's frames aligned straight
    from the root show is a torn solid, however small in absolute terms."""
    reference = max(float(reference), 0.0)
    scale = TAIL_SCALE + TAIL_RELATIVE * reference
    if reference > 0.0:
        scale = min(scale, max(TAIL_FLOOR * reference, TAIL_LEAST))
    return scale


def alignment_confidence(residual, distortion_tail, model_size, reference=0.0, colour=None, colour_floor=None,
                         tail_free=TAIL_WITH_COLOUR):
    """Per-frame confidence in 0..1: ``exp(-badness)`` (1 for the root; 1/e at each scale)."""
    return np.exp(-alignment_badness(residual, distortion_tail, model_size, reference, colour, colour_floor,
                                     tail_free))


def tail_reference(distortion_tail, parent, root):
    """The capture's own distortion floor: the median tail of the frames aligned from the root.

    A frame aligned in one step from the root has had no chance to inherit a slip, so what its
    solid shows is what this body and its clothes do anyway (about 0.3 on a tight-fitting body,
    about 10 with a bell-sleeved dress). 0 when the root has no children.
    """
    parent = np.asarray(parent)
    children = np.flatnonzero((parent == int(root)) & (np.arange(len(parent)) != int(root)))
    if len(children) == 0:
        return 0.0
    return float(np.median(np.asarray(distortion_tail, dtype=np.float64)[children]))


def repair_alignment(aligner, meshes, aligned, *, dissimilarity=None, yaw=None, candidates=2, budget=None,
                     progress=None, runner=None, strategy="root_first", min_yield=MIN_YIELD):
    """Align low-confidence frames again from the root and from trusted similar frames.

    Parameters
    ----------
    aligner : PairwiseAligner        the one that aligned the frames
    meshes : sequence of Mesh-like   the captured frames (as for ``align_tree``)
    aligned : AlignedFrames          from ``align_tree``; updated in place (vertices, residuals,
                                     distortions, parent, confidence, repaired, poses)
    dissimilarity : (N, N) array or None   picks the trusted frames most like each flagged one
    yaw : (N, N) array or None       rotation hints (degrees about +Y) between frames
    candidates : int                 trusted frames tried besides the root
    budget : float or None           at most this many pairwise alignments per frame of the
                                     whole capture go to repairs (None: no limit); when the
                                     flagged frames would need more, those ``strategy`` puts
                                     first are repaired and the others stay flagged
    progress : callable(done, total) or None
    runner : task runner or None     align the repairs as tasks of this runner (:mod:`engine.tasks`):
                                     in waves, every remaining frame's alignments at once from the
                                     frames as they stand, then applied in order while the sources
                                     the serial pass would pick are among them; the same result
    strategy : {"root_first", "together"}
        "root_first" (default): the flagged frames first from the root alone, the frames most
        like the root first as far as the budget goes (one wave of independent alignments: the
        root's pose never changes), then the frames still below ``TRUSTED`` from the trusted
        similar frames (and turned round), the lowest confidence first; "together" (the repair
        before 2026-11-30): each flagged frame from all its sources at once, the lowest
        confidence first (docs/evaluation.md, "The repair priced")
    min_yield : float
        each phase goes through its frames in runs of about ``YIELD_CHUNK`` alignments; a run
        that mends (replaces the alignment of) fewer frames than ``min_yield`` times the
        alignments it spent ends the phase: its remaining frames are not tried in it (those the
        root phase leaves go on to the next phase, as the frames the root did not mend do). The
        phases ended so are named in ``aligned.repair_stopped``. The root phase goes most like the
        root first, so a run that fails is followed by frames less likely still to be mended; the
        others go parents first, each run a sample of the phase's yield. 0: never stop

    Returns
    -------
    aligned : AlignedFrames   with ``confidence`` and ``repaired`` filled in

    Notes
    -----
    Of the frame's own alignment and the new ones, the one of lowest badness (fit and distortion
    tail) wins. With vertex colours, a frame whose colours disagree ``TURN_COLOUR`` times more than
    the trusted frames' (median of up to ``TURN_SAMPLE``) is also aligned from its own alignment
    turned half round about +Y (:func:`turned_round`; one more alignment of the budget, the last
    one planned), and only results whose colours agree within ``COLOUR_MARGIN`` of the best agreement compete: a
    body turned the wrong way round can fit and tear no worse than the right one, but its front
    lands on its back (docs/evaluation.md, "Frames far apart").
    """
    from engine.align.propagation import mesh_arrays
    from engine.surface import model_size

    size = model_size(aligner.V)
    root = int(aligned.root)
    reference = tail_reference(aligned.distortion_tail, aligned.parent, root)
    colour, floor, tail_free = colour_terms(aligned, aligner.colors is not None and aligner.options.colour_weight > 0)
    confidence = alignment_confidence(aligned.residual, aligned.distortion_tail, size, reference, colour, floor,
                                      tail_free)
    confidence[root] = 1.0
    repaired = np.zeros(len(confidence), dtype=bool)
    depth_order = _tree_order(aligned.parent, root)
    flagged = [f for f in depth_order if confidence[f] < TRUSTED]
    limit = np.inf if budget is None else int(np.floor(float(budget) * len(confidence)))
    use_colours = aligner.colors is not None
    current_colour = {}  # flagged frame -> how well the colours of its alignment before the repair agree
    turn = set()         # flagged frames also aligned from their own alignment turned round
    if use_colours and flagged and limit > 0:  # (the colours are read for the repair's sake alone)
        current_colour = {f: _colour_now(aligner, meshes[f], aligned.vertices[f]) for f in flagged}
        trusted = [f for f in depth_order if confidence[f] >= TRUSTED and f != root]
        sample = [trusted[i] for i in np.unique(np.linspace(0, len(trusted) - 1, min(len(trusted), TURN_SAMPLE))
                                                .astype(np.int64))] if trusted else []
        usual = float(np.median([_colour_now(aligner, meshes[f], aligned.vertices[f]) for f in sample])) if sample else 0.0
        turn = {f for f in flagged if not current_colour[f] <= TURN_COLOUR * usual}  # (NaN: turned too)
    if strategy not in ("together", "root_first"):
        raise ValueError(f"strategy must be 'root_first' or 'together', got {strategy!r}")
    first = strategy == "root_first"

    def affordable(frames, cost, planned, near=False):
        """``frames`` (in the tree's order) the budget reaches: the lowest confidence first, or
        (``near``, with a dissimilarity) the most like the root first, and then in that order (the
        root's alignments are independent of each other: their order changes nothing but where
        the yield stop falls)."""
        if near and dissimilarity is not None:
            row = np.asarray(dissimilarity)[root]
            key = lambda f: (float(row[f]), f)  # noqa: E731
        else:
            key = lambda f: (confidence[f], f)  # noqa: E731
        if budget is not None:
            chosen = set()
            for f in sorted(frames, key=key):
                if planned + cost(f) <= limit:
                    chosen.add(f)
                    planned += cost(f)
            frames = [f for f in frames if f in chosen]
        return sorted(frames, key=key) if near and dissimilarity is not None else frames

    versions = {}  # frame -> how often its pose was replaced: the runner's results name the pose they started from

    def plan(frame, spent, phase="all"):
        """The sources the frame is aligned from now (the trusted set grows as frames are repaired);
        the frame itself stands for its own alignment turned round (with colours). ``phase``:
        "root" (the root alone), "others" (all but the root) or "all"."""
        parent = aligned.parent[frame]
        sources = [] if parent == root or phase == "others" else [root]  # the same source again: the same result
        if phase != "root" and dissimilarity is not None:
            trusted = np.flatnonzero(confidence >= TRUSTED)
            others = trusted[(trusted != root) & (trusted != parent)]
            others = others[np.argsort(np.asarray(dissimilarity)[frame, others], kind="stable")]
            sources += [int(s) for s in others[:max(0, int(candidates))]]
        if phase == "limbs":
            return [GRAFT] if spent < limit and grafted(frame) is not None else []  # no graft made past the budget
        if phase != "root" and frame in turn:  # (a flagged frame is never a trusted source: the frame means this)
            sources.append(int(frame))
        if spent + len(sources) > limit:
            sources = sources[:max(0, int(limit) - spent)]
        return sources

    grafts, library = {}, []  # frame -> its pose with limbs grafted (or None); the library, made when first needed

    def grafted(frame):
        if frame not in grafts:
            if not library:  # every frame's pose: a limb's is taken only where it fits the frame best
                from engine.align.limb_graft import LimbLibrary
                library.append(LimbLibrary(aligner, np.asarray(aligned.vertices)[depth_order]))
            target = TargetSurface(*mesh_arrays(meshes[frame], use_colours))
            grafts[frame] = library[0].pose(aligned.poses[frame], aligned.vertices[frame], target)
        return grafts[frame]

    def job(frame, sources):
        starts = [(grafts[frame], None) if s == GRAFT else (turned_round(aligned.poses[s]), None) if s == frame else
                  (aligned.poses[s], None if yaw is None else float(yaw[frame, s])) for s in sources]
        return mesh_arrays(meshes[frame], use_colours), starts

    def apply(frame, sources, results):
        entries = [(alignment_badness(aligned.residual[frame], aligned.distortion_tail[frame], size, reference,
                                      None if colour is None else colour[frame], floor, tail_free),
                    current_colour.get(frame, float("nan")), None, None)]
        for source, result in zip(sources, results, strict=True):
            entries.append((alignment_badness(result.residual, result.distortion_tail, size, reference,
                                              None if colour is None else result.colour_mean, floor, tail_free),
                            result.colour_distance, source, result))
        colours = np.array([entry[1] for entry in entries])
        if np.all(np.isfinite(colours)):  # the appearance rules out a body turned the wrong way
            entries = [entry for entry in entries if entry[1] <= (1.0 + COLOUR_MARGIN) * colours.min()]
        best_badness, _, best_source, best = min(entries, key=lambda entry: entry[0])  # the frame's own wins a tie
        if best is not None:
            aligned.vertices[frame] = best.V
            aligned.residual[frame], aligned.residual_max[frame] = best.residual, best.residual_max
            aligned.distortion[frame], aligned.distortion_tail[frame] = best.distortion, best.distortion_tail
            if aligned.colour is not None:
                aligned.colour[frame] = best.colour_mean
            if best_source not in (frame, GRAFT):  # (its own alignment turned round or grafted keeps its parent)
                aligned.parent[frame] = best_source
            aligned.poses[frame] = best.X
            if aligned.pulled is not None:
                aligned.pulled[frame] = best.pulled
            versions[frame] = versions.get(frame, 0) + 1
            repaired[frame] = True
            confidence[frame] = float(np.exp(-best_badness))
            current_colour[frame] = best.colour_distance  # (a later phase weighs it as the frame's own)

    similar = max(0, int(candidates)) if dissimilarity is not None else 0  # trusted similar frames a frame tries
    spent, done, steps = 0, 0, []
    if first:  # every flagged frame from the root, then those still flagged from the others
        steps.append(("root", affordable(flagged, lambda f: 1 if aligned.parent[f] != root else 0, 0, near=True)))
        if aligner.options.graft_limbs:  # then their limbs grafted from the other frames' poses
            steps.append(("limbs", None))
        steps.append(("others", None))
    else:
        steps.append(("all", affordable(flagged, lambda f: (1 if aligned.parent[f] != root else 0) + similar
                                        + (1 if f in turn else 0), 0)))
        if aligner.options.graft_limbs:  # then the frames no source mended, their limbs grafted
            steps.append(("limbs", None))
    total = len(steps[0][1])
    progress = forward_only(progress)  # a wave's share can run ahead of the frames applied after it
    if progress is not None and total:  # the stage shows from its start
        progress(0, total)
    if runner is None:
        local, shared = SerialRunner(aligner), None
    else:
        from engine.align.pieces import portable_aligner

        local, shared = runner, portable_aligner(aligner)  # one object: a ProcessRunner keeps its processes
    stopped = []
    for phase, frames in steps:
        if frames is None:  # the frames the root (or, for the limbs, any source) did not mend
            still = [f for f in flagged if confidence[f] < TRUSTED]
            frames = affordable(still, lambda f: 1 if phase == "limbs" else similar + (1 if f in turn else 0), spent)
            total += len(frames)
        k = 0
        while k < len(frames):  # in runs, each judged by how many frames it mended
            run, planned = [], 0
            while k < len(frames) and (not run or planned < YIELD_CHUNK):
                planned += len(plan(frames[k], spent + planned, phase))
                run.append(frames[k])
                k += 1
            before, mended_before = spent, {f: versions.get(f, 0) for f in run}
            spent, done = run_phase(run, phase, plan, job, apply, local, shared, versions, spent, done, total,
                                    progress)
            mended = sum(versions.get(f, 0) > mended_before[f] for f in run)
            if k < len(frames) and spent > before and mended < float(min_yield) * (spent - before):
                stopped.append(phase)  # the phase stopped paying: its other frames are not tried
                total -= len(frames) - k
                if progress is not None:
                    progress(done, total)
                break
    aligned.repair_spent = spent
    aligned.repair_stopped = stopped
    aligned.confidence = confidence
    aligned.repaired = repaired
    return aligned


def colour_terms(aligned, cues):
    """(per-frame colour disagreement, the root's floor, the tail they excuse) for the confidence
    when the frames have colours, else (None, None, 0).

    With colour cues on (``cues``: the colours carry texture) the colours excuse the distortion tail
    up to ``TAIL_WITH_COLOUR``. With them off, a mesh too coarse for its colours to guide the
    matching still shows, frame by frame, how far its colours landed from the root's, but not a
    leg on the other leg's place in the same trousers: there the colours only add to the tail."""
    colour = getattr(aligned, "colour", None)
    if colour is None or not np.isfinite(colour[int(aligned.root)]):
        return None, None, 0.0
    return colour, float(colour[int(aligned.root)]), TAIL_WITH_COLOUR if cues else 0.0


def turned_round(X):
    """Tet vertices X turned half a turn about the vertical (+Y) axis through their centroid."""
    X = np.asarray(X, dtype=np.float64)
    centre = X.mean(axis=0)
    turned = X - centre
    turned[:, 0] *= -1.0
    turned[:, 2] *= -1.0
    return turned + centre


def _colour_now(aligner, mesh, vertices):
    """How well the colours of a frame's aligned ``vertices`` agree with the root's (median RGB
    distance against the root's colours, :func:`engine.align.appearance.colour_distance`; NaN
    without colours)."""
    from engine.align.appearance import colour_distance
    from engine.align.propagation import mesh_arrays

    V, F, C = mesh_arrays(mesh, True)
    return colour_distance(vertices, aligner.colors, TargetSurface(V, F, C), aligner.colour_regions)


def _tree_order(parent, root):
    """Frames ordered parents before children (breadth first from the root)."""
    parent = np.asarray(parent)
    children = [[] for _ in parent]
    for node, p in enumerate(parent):
        if p >= 0:
            children[p].append(node)
    order, queue = [], [root]
    while queue:
        node = queue.pop(0)
        order.append(node)
        queue.extend(children[node])
    return order


__all__ = ["alignment_badness", "alignment_confidence", "colour_terms", "repair_alignment", "repair_task", "tail_reference",
           "tail_scale", "turned_round"]

"""Alignment of unstructured capture frames end to end (Casas et al. 2012, section 3).

``run = align_captures(meshes, lengths)``: shape similarity of all frames, the similarity tree
(or a frame-to-frame chain, the baseline), the root's tet mesh, and the alignment of every frame
along the tree. The CLI (``morphspace align``, ``eval-align``) and the align job call it.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field, is_dataclass, replace

import numpy as np

from engine.align.pairwise import AlignmentOptions
from engine.align.propagation import AlignedFrames, align_tree
from engine.align.repair import alignment_confidence, colour_terms, repair_alignment, tail_reference
from engine.align.root_choice import ROOT_SLACK, choose_root, surface_handles
from engine.align.root_race import (finalists, no_race_reason, no_trial_reason, race_frames, race_in_processes,
                                    race_score, sub_similarity)
from engine.align.root_trial import root_setup, trial_candidates, trial_probes, try_roots
from engine.align.similarity import shape_dissimilarity
from engine.align.similarity_tree import DEFAULT_TREE, chain_tree, similarity_tree
from engine.surface import orient_outward, surface_area


@dataclass
class CaptureAlignment:
    """Everything :func:`align_captures` computed.

    Attributes
    ----------
    similarity : engine.align.similarity.ShapeSimilarity
    tree : engine.align.similarity_tree.SimilarityTree   the tree the frames were aligned along
                                                    (a chain for ``method="sequential"``)
    aligned : AlignedFrames
    timings : dict   seconds for "similarity", "tree" (with choosing the root), "trial" (when the root
                     was tried), "race" (when it was raced; a whole race's winning run is counted
                     in the next three), "tetrahedralize", "align", "repair"
    method : str     "tree" or "sequential"
    tets : (V_tet, T)   the root's tet mesh (reusable for another run with the same root)
    colour_cues : bool  whether vertex colours were used as local matching cues
    turned : dict       frame index -> faces whose winding was reversed so that the frame faces
                        outward (:func:`engine.surface.orient_outward`); frames as read are absent
    root_trial : dict or None   with ``root_choice`` "trial", "race" or "auto": the candidate roots
                        tried, the probe frames, each candidate's badness per probe and mean, its
                        handles and the spread's choice (:func:`engine.align.root_trial.try_roots`); when
                        raced also ``race``: ``finalists``, ``frames`` (how many each aligned),
                        ``confidence`` (each finalist's mean) and ``winner``; None when no trial ran
    root_reason : str or None   when no trial or no race ran although ``root_choice`` asked for it,
                        why (``root`` given, or fewer than ``TRIAL_MIN_FRAMES`` frames: neither;
                        "auto" on a densely tracked take, ``root_race.neighbour_share``: no race)
    """

    similarity: object
    tree: object
    aligned: AlignedFrames
    timings: dict
    method: str
    tets: tuple
    colour_cues: bool = False
    turned: dict = field(default_factory=dict)
    root_trial: dict = None
    root_reason: str = None


COLOUR_WEIGHT = 1.0   # AlignmentOptions.colour_weight when colour cues are on and the options leave it 0
FINE_EDGE = 0.016     # "auto" colour cues: root median edge length below this fraction of sqrt(surface area)


def colours_carry_texture(vertices, faces):
    """Whether a mesh is sampled finely enough for its vertex colours to carry surface texture.

    True when the median edge is shorter than ``FINE_EDGE`` (1.6%) of the square root of the
    surface area, which a pose does not change: the studio preset's 10,000-vertex frames have
    1.14-1.17% in every pose, the demo preset's 3,000-vertex ones 1.9-2.2%, the tiny preset's
    1,000-vertex ones 3.2%. (Against the model size, as before, a crouch or a flared skirt moved
    the same studio body between 1.18% and 1.63%, so a crouching root lost its colour cues.)
    Coarser meshes sample a texture at a few vertices per stripe or check, and colour cues then
    pull matches the wrong way (tiny preset: mean error 0.79% -> 1.22% of the model size with
    them); on the studio dance they cut it from 0.83% to 0.50% (docs/evaluation.md).
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if len(F) == 0:
        return False
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    median = float(np.median(np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)))
    return median < FINE_EDGE * np.sqrt(surface_area(V, F))


ROOT_CHOICES = ("auto", "race", "trial", "apart", "central")


def align_captures(meshes, lengths, *, method="tree", tree_kind=DEFAULT_TREE, root=None, root_choice="auto",
                   options=None, window=2,
                   workers=1, retries=3, tets=None, use_colors="auto", seed=0, similarity=None, repair=True,
                   repair_budget=0.25, progress=None, runner=None):
    """Shape similarity, tree and alignment of unstructured frames of several sequences.

    Parameters
    ----------
    meshes : list of Mesh-like (vertices, faces, colors)   all frames, sequences concatenated
    lengths : (S,) int array    frames per sequence
    method : {"tree", "sequential"}
        "tree" aligns along the shape similarity tree (paper section 3); "sequential" tracks
        frame to frame from the same root (forwards and backwards, sequences end to end), the
        baseline, with no retries.
    tree_kind : {"mst", "paths", "steps"}   the similarity tree (:func:`engine.align.similarity_tree.similarity_tree`):
                                the paper's minimum spanning tree, or cheapest paths from the
                                root with big steps penalised
    root : int or None          root frame (default: chosen by ``root_choice``)
    root_choice : {"auto", "race", "trial", "apart", "central"}
                                without ``root``: "central" is the paper's, the minimum spanning
                                tree's most central frame; "apart" a frame nearly as central whose
                                limbs are apart, so no merged contact (a hand on a hip, a sleeve
                                against a skirt) is tied into every aligned frame
                                (:func:`engine.align.root_choice.choose_root`); "trial"
                                the apart choice and a few other central frames each align a few
                                probe frames, and the one that aligns them best is the root
                                (:mod:`engine.align.root_trial`; captures of fewer than
                                ``TRIAL_MIN_FRAMES`` frames, or with ``tets`` given: "apart");
                                "race" the trial's two best each align the capture (or 64 frames
                                of one over 128), the more confident alignment wins
                                (:mod:`engine.align.root_race`; with the tree only); "auto"
                                (default) "race", except on one densely tracked take (a single
                                sequence whose tree's steps join neighbours in time,
                                ``TRACKED_SHARE`` of them or more:
                                :func:`engine.align.root_race.neighbour_share`): "trial"
    options : AlignmentOptions
    window : int                temporal filter half-width
    workers : int               processes for the dissimilarity matrix and for aligning
                                independent pieces of the tree
    retries : int               see :func:`engine.align.propagation.align_tree`
    tets : (V_tet, T) or None   a tet mesh of the root (default: tetrahedralised here)
    use_colors : bool or "auto" also use vertex colours as local matching cues (when every frame has
                                colours; ``options.colour_weight``, ``COLOUR_WEIGHT`` if that is 0);
                                "auto": when the root is sampled finely enough for its colours to
                                carry texture (:func:`colours_carry_texture`). Whatever this says,
                                colours on every frame decide between a body and the same body
                                turned front to back
    seed : int
    similarity : ShapeSimilarity or None   reuse an earlier computation on the same frames
    repair : bool               with the tree: align frames of low confidence again from the
                                root and trusted similar frames (:mod:`engine.align.repair`)
    repair_budget : float or None   pairwise alignments per frame the repair may spend (the
                                flagged frames most like the root first: :mod:`engine.align.repair`;
                                None: every flagged frame is repaired)
    progress : callable(stage, done, total) or None
        stages "histograms", "dissimilarity", "root", "trial", "race", "align", "repair"
    runner : task runner or None   runs the histogram chunks, matrix blocks, tree pieces and repairs as
                                tasks (:mod:`engine.tasks`, e.g. on a Dask cluster) instead of
                                ``workers``; the result is the same

    Returns
    -------
    CaptureAlignment
    """
    if method not in ("tree", "sequential"):
        raise ValueError(f"method must be 'tree' or 'sequential', got {method!r}")
    if root_choice not in ROOT_CHOICES:
        raise ValueError(f"root_choice must be one of {ROOT_CHOICES}, got {root_choice!r}")
    if use_colors not in (True, False, "auto"):
        raise ValueError(f"use_colors must be True, False or 'auto', got {use_colors!r}")
    lengths = np.asarray(lengths, dtype=np.int64)
    meshes, turned = _outward(meshes)
    timings = {}
    started = time.perf_counter()
    if similarity is None:
        similarity = shape_dissimilarity(meshes, lengths, window=window, workers=workers, progress=progress,
                                         runner=runner)
    timings["similarity"] = time.perf_counter() - started
    started = time.perf_counter()
    chooser = _apart(meshes, progress) if root is None and root_choice != "central" else None
    tree = similarity_tree(similarity.dissimilarity, root=root, kind=tree_kind, choose_root=chooser, lengths=lengths)
    timings["tree"] = time.perf_counter() - started
    # colours, when every frame has them, always settle front-back ambiguities (PairwiseAligner
    # ._orientation_score); ``use_colors`` adds them as local matching cues (options.colour_weight)
    colours = all(getattr(m, "colors", None) is not None for m in meshes)
    options = options or AlignmentOptions()
    trial = None
    tried = {}
    tries = chooser is not None and root_choice in ("auto", "trial", "race")
    reason = no_trial_reason(len(meshes)) if tries else \
        "the root given: no trial or race" if root is not None and root_choice in ("auto", "race", "trial") else None
    if tries and reason is None and tets is None:
        started = time.perf_counter()
        # frames with as few handles as the choice allows are tried first, the others only after them
        candidates = trial_candidates(similarity.dissimilarity, chooser.centrality, tree.root, slack=ROOT_SLACK,
                                      allowed=chooser.report["allowed"])
        if len(candidates) > 1:
            probes = trial_probes(len(meshes), candidates)
            # the probes are far steps, where the ring (engine.align.ring) would run on most: without it
            chosen, trial, tried = try_roots(meshes, candidates, probes, similarity.yaw,
                                             options=replace(options, ring_margin=0.0), use_colors=use_colors,
                                             colours=colours, seed=seed, runner=runner, workers=workers,
                                             progress=(lambda d, t: progress("trial", d, t)) if progress else None)
            trial["spread_choice"] = int(tree.root)
            # counted again (milliseconds): a candidate that fills a place may lie beyond the 64 the choice counted
            trial["handles"] = [surface_handles(meshes[c].vertices, meshes[c].faces) for c in candidates]
            tets = tried[chosen]
            if chosen != tree.root:
                tree = similarity_tree(similarity.dissimilarity, root=chosen, kind=tree_kind, lengths=lengths)
        timings["trial"] = time.perf_counter() - started
    settings = dict(options=options, use_colors=use_colors, colours=colours, seed=seed, workers=workers,
                    retries=retries, runner=runner, repair=repair, repair_budget=repair_budget)
    run = None
    races = trial is not None and root_choice in ("auto", "race") and method == "tree" and len(finalists(trial)) > 1
    reason = no_race_reason(tree.parent, lengths, root_choice) if races else reason
    if races and reason is None:
        started = time.perf_counter()
        tree, run = _race(meshes, lengths, similarity, trial, tried, tree_kind, settings, progress)
        tets = tried[int(tree.root)]
        # a whole race's winning run is the alignment: its stages are counted as theirs
        timings["race"] = time.perf_counter() - started - (sum(run[3].values()) if run is not None else 0.0)
    if method == "sequential":
        tree = chain_tree(lengths, tree.root)
    if run is not None:
        aligned, tets, cues, spent = run
    else:
        aligned, tets, cues, spent = _align_from(meshes, lengths, similarity, tree, method, tets=tets,
                                                 progress=progress, **settings)
    timings.update(spent)
    return CaptureAlignment(similarity=similarity, tree=tree, aligned=aligned, timings=timings, method=method,
                            tets=tets, colour_cues=bool(cues), turned=turned, root_trial=trial, root_reason=reason)


def _align_from(meshes, lengths, similarity, tree, method, *, options, use_colors, colours, seed, tets, workers,
                retries, runner, repair, repair_budget, progress):
    """Align every frame along ``tree`` from its root: the root's aligner (its tet mesh ``tets``,
    or tetrahedralised here), the alignment and, with the tree, the repair.

    Returns (aligned frames, the root's tet mesh, colour cues on, {stage: seconds})."""
    timings = {}
    base = meshes[tree.root]
    started = time.perf_counter()
    aligner, options, cues, kept = root_setup(base, options, use_colors, colours, seed, tets=tets,
                                              label=getattr(base, "source", None) or f"frame {tree.root}")
    tets = (aligner.V_tet, aligner.T)
    timings["tetrahedralize"] = time.perf_counter() - started
    started = time.perf_counter()
    aligned = align_tree(aligner, meshes, tree, yaw=similarity.yaw,
                         dissimilarity=similarity.dissimilarity if method == "tree" else None,
                         retries=retries if method == "tree" else 0, workers=workers, runner=runner,
                         progress=(lambda d, t: progress("align", d, t)) if progress else None, lengths=lengths)
    aligned.root_kept = kept
    timings["align"] = time.perf_counter() - started
    started = time.perf_counter()
    if method == "tree" and repair:
        from engine.tasks import ProcessRunner

        # without a runner, the repair's waves still use the ``workers`` processes
        with contextlib.nullcontext(runner) if runner is not None or workers <= 1 else ProcessRunner(workers) as local:
            repair_alignment(aligner, meshes, aligned, dissimilarity=similarity.dissimilarity, yaw=similarity.yaw,
                             candidates=retries, budget=repair_budget,
                             progress=(lambda d, t: progress("repair", d, t)) if progress else None, runner=local)
    else:
        _confidence_only(aligned, cues=bool(cues))
    timings["repair"] = time.perf_counter() - started
    return aligned, tets, bool(cues), timings


def _race(meshes, lengths, similarity, trial, tried, tree_kind, settings, progress):
    """The trial's best candidates each align the capture (or :func:`race_frames` of it); the
    one with the highest mean confidence wins (:mod:`engine.align.root_race`). Adds ``race`` to
    the trial's report.

    Returns (the winner's tree, its whole run as :func:`_align_from` returns it, or None when a
    subset was raced and the capture is still to be aligned)."""
    final = finalists(trial)
    frames = race_frames(len(meshes), final)
    whole = len(frames) == len(meshes)
    sub = meshes if whole else [meshes[f] for f in frames]
    similar = similarity if whole else sub_similarity(similarity, frames)
    sub_lengths = lengths if whole else None
    trees = [similarity_tree(similar.dissimilarity, root=frames.index(c), kind=tree_kind, lengths=sub_lengths)
             for c in final]
    if settings["runner"] is None and settings["workers"] >= 2:
        # the finalists side by side, one process each: a race's tree is one or two pieces, so a
        # finalist alone keeps one core busy (the same result: it does not depend on ``workers``)
        done = race_in_processes(sub, sub_lengths, similar, trees, [tried.get(c) for c in final], settings,
                                 progress)
    else:
        done = [_align_from(sub, sub_lengths, similar, tree, "tree", tets=tried.get(c),
                            progress=_race_progress(progress, k * len(frames), len(final) * len(frames)), **settings)
                for k, (c, tree) in enumerate(zip(final, trees))]
    runs = {c: (tree, run) for c, tree, run in zip(final, trees, done)}
    scores = [race_score(_race_confidence(run[0], run[2]), tree.root) for tree, run in runs.values()]
    winner = final[int(np.argmax(scores))]  # the first of equals: the trial's better candidate
    trial["race"] = {"finalists": final, "frames": len(frames), "confidence": [round(x, 4) for x in scores],
                     "winner": int(winner)}
    if whole:
        return runs[winner]
    return similarity_tree(similarity.dissimilarity, root=winner, kind=tree_kind, lengths=lengths), None


def _race_progress(progress, offset, total):
    """A finalist's alignment reported as the "race" stage (its frames after ``offset`` of ``total``)."""
    if progress is None:
        return None

    def report(stage, done, _):
        if stage == "align":
            progress("race", offset + done, total)
    return report


def _outward(meshes):
    """The frames with their faces wound outward, and {frame: faces turned} for those that were not."""
    out, turned = [], {}
    for i, mesh in enumerate(meshes):
        faces, count = orient_outward(mesh.vertices, mesh.faces)
        if count:
            turned[i] = count
            mesh = replace(mesh, faces=faces) if is_dataclass(mesh) else _with_faces(mesh, faces)
        out.append(mesh)
    return out, turned


def _with_faces(mesh, faces):
    """A shallow copy of a Mesh-like object with other faces."""
    from copy import copy

    other = copy(mesh)
    other.faces = faces
    return other


def _apart(meshes, progress):
    """``choose_root`` for :func:`similarity_tree`: central, with the limbs apart (the
    centrality it was given kept as ``.centrality`` and its report as ``.report``, for the root
    trial)."""
    def choose(centrality):
        choose.centrality = np.asarray(centrality)
        root, choose.report = choose_root(meshes, centrality,
                                          progress=(lambda d, t: progress("root", d, t)) if progress else None)
        return root
    return choose


def _race_confidence(aligned, cues):
    """The confidence a race ranks its finalists by: the alignment's own with colour cues on; with
    them off, the fit and the tail alone. (Colours too coarse for the cues still flag frames, but
    each finalist's colours count against its own floor, and on the tiny preset's walk and run that
    turned the race to a root whose alignment left the run facing backwards, unseen by either.)"""
    if cues:
        return aligned.confidence
    from engine.surface import model_size

    reference = tail_reference(aligned.distortion_tail, aligned.parent, aligned.root)
    confidence = alignment_confidence(aligned.residual, aligned.distortion_tail, model_size(aligned.root_vertices),
                                      reference)
    confidence[aligned.root] = 1.0
    return confidence


def _confidence_only(aligned, cues=False):
    """Fill ``confidence`` (and an all-false ``repaired``) without aligning anything again (with
    colours, the confidence reads their disagreement too; ``cues``: colour cues are on)."""
    from engine.surface import model_size

    reference = tail_reference(aligned.distortion_tail, aligned.parent, aligned.root)
    colour, floor, tail_free = colour_terms(aligned, cues)
    aligned.confidence = alignment_confidence(aligned.residual, aligned.distortion_tail,
                                              model_size(aligned.root_vertices), reference, colour, floor, tail_free)
    aligned.confidence[aligned.root] = 1.0
    aligned.repaired = np.zeros(len(aligned.confidence), dtype=bool)
    return aligned


__all__ = ["COLOUR_WEIGHT", "ROOT_CHOICES", "CaptureAlignment", "align_captures", "colours_carry_texture"]

"""Single alignment steps from a perfect start: what the pairwise aligner adds per step.

A frame deep in the tree inherits its parent's error and adds its own step's. This measures the
step alone: for every pair ``A>B`` the frame A is the root (so its alignment is exact) and B is
aligned from it (``align_captures`` on the two frames, no repair), scored per part against the
generator's truth (mean error over the root's vertices, % of the model size). With
``--oracle-rigid`` each pair is also aligned from the true rigid placement (the rotation and
translation that best carry A's vertices to their true positions in B, Kabsch) instead of the
aligner's rigid start, and that placement alone is scored: if the oracle start is no better, the
rigid start is not what fails. It also deforms A's solid onto the true positions (the aligner's
own as-rigid-as-possible solve with the truth as its goals) and aligns B from that true pose:
what the fit gives from the answer itself says how much of a step's error the aligner's
objective makes (it leads away from the truth) and how much its search does (it stops short of
it).

    .venv/bin/python benchmarks/align_steps.py /tmp/studio-dance --sequence dance \\
        --pairs 259:260,258:257,245:246,250:251 [--every 40] [--oracle-rigid] [--option NAME=VALUE] \\
        [--out result.json]
    .venv/bin/python benchmarks/align_steps.py --tiny --out /tmp/align_steps.json

``--every K`` adds the pairs ``a:a+1`` for a = 10, 10 + K, ... (single steps along the whole take).
``--segments K`` also lists each pair's K worst skeleton segments: every root vertex takes the
segment (the joint that owns it, from the dataset's ``template/body.npz``) of the template
vertex it lies nearest on the true surface, and a segment's error is its vertices' mean
(``lowerarm_r 31.2%``: the right forearm did not follow a punch).
``--oracle-pull NAMES`` (comma separated parts of skeleton segment names, ``arm,hand``) also aligns
each pair with the pairwise aligner directly (its own rigid start), then pulls the root vertices
of those segments onto their true places (the aligner's own solve, the rest of the surface held
where the alignment left it) and fits again from there: whether a part put in its place stays
there through the fit (the studio dance's arms do; its hands alone do not).
``--tiny`` (the test suite's smoke run) needs no dataset: two pairs of the generator's 1,000-vertex
run at 15 fps, small alignment settings, one part, the oracles included (the tiny rig's elbows and
wrists pulled); ``--out`` is required.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

from _tiny import emit, parse_arguments
from align_breakdown import parse_options, part_counts
from align_speed import load_frames

TINY = {"pairs": "0:1,3:2", "options": ["patches=8", "levels=2"], "oracle_rigid": True, "segments": 3,
        "oracle_pull": "elbow,wrist"}


def parse_pairs(text, every, frames):
    """``"A:B,C:D"`` (and ``--every``) -> [(A, B), ...] within 0..frames-1."""
    pairs = []
    for item in filter(None, (text or "").split(",")):
        a, sep, b = item.partition(":")
        if not sep:
            raise SystemExit(f"--pairs {item!r}: expected A:B (frame numbers)")
        pairs.append((int(a), int(b)))
    if every:
        pairs += [(a, a + 1) for a in range(10, frames - 1, every)]
    pairs = list(dict.fromkeys(pairs))  # each pair once, in the order given
    for a, b in pairs:
        if not (0 <= a < frames and 0 <= b < frames) or a == b:
            raise SystemExit(f"pair {a}:{b}: frames must differ and lie in 0..{frames - 1}")
    return pairs


def template_segments(dataset, tiny):
    """(segment of every template vertex, joint names) from the dataset's rig, or the tiny body's."""
    import numpy as np

    if tiny:
        from _tiny import TINY_VERTICES

        from engine.synthetic import build_body

        body = build_body(TINY_VERTICES)
        return np.asarray(body.segment), [str(name) for name in body.skeleton.names]
    path = Path(dataset) / "template" / "body.npz"
    if not path.is_file():
        raise SystemExit(f"--segments: {path} is missing (datasets written by `morphspace synth` have it)")
    with np.load(path) as rig:
        return rig["segment"], [str(name) for name in rig["joint_names"]]


def worst_segments(pct, root_vertices, truth_root, faces, segment, names, count):
    """The ``count`` segments with the highest mean error: {name: % of the model size}."""
    import numpy as np

    from engine.align.evaluation import nearest_template_vertices

    owner = segment[nearest_template_vertices(root_vertices, truth_root, faces)]
    means = {names[k]: float(pct[owner == k].mean()) for k in np.unique(owner)}
    worst = sorted(means.items(), key=lambda item: item[1], reverse=True)[:count]
    return {name: round(value, 3) for name, value in worst}


def _pair_aligner(mesh_a, mesh_b, truth_ab, faces, options):
    """The pairwise aligner of A (colour cues as ``align_captures`` gives them), B's target surface,
    A's vertices and their true positions in B."""
    from dataclasses import replace

    from engine.align.captures import COLOUR_WEIGHT
    from engine.align.evaluation import surface_coordinates, true_positions
    from engine.align.matching import TargetSurface
    from engine.align.pairwise import PairwiseAligner
    from engine.surface import main_components

    V, F, kept = main_components(mesh_a.vertices, mesh_a.faces)
    colours = None if mesh_a.colors is None else mesh_a.colors[kept]
    if colours is not None and mesh_b.colors is not None and not options.colour_weight:
        options = replace(options, colour_weight=COLOUR_WEIGHT)
    aligner = PairwiseAligner(V, F, colours, options=options)
    target = TargetSurface(mesh_b.vertices, mesh_b.faces, mesh_b.colors)
    face, bary, _ = surface_coordinates(V, truth_ab[0], faces)
    return aligner, target, V, true_positions(truth_ab[1:2], faces, face, bary)[0]


def oracle_step(mesh_a, mesh_b, truth_ab, faces, options):
    """B aligned from A's true rigid placement and from its true pose: (aligned from the placement,
    the placement alone, aligned from the true pose, the true pose alone, the true positions in B
    of A's vertices)."""
    import numpy as np

    from engine.align.limb_graft import carry
    from engine.align.rigid import kabsch

    aligner, target, V, true = _pair_aligner(mesh_a, mesh_b, truth_ab, faces, options)
    R, t = kabsch(V, true, np.ones(len(V)))
    X = aligner.V_tet @ R.T + t
    result = aligner._fit(X, target)
    # the true pose: the root's solid pulled onto the true positions by the aligner's own solve
    X = carry(aligner, X, true)
    from_pose = aligner._fit(X, target)
    return result.V, V @ R.T + t, from_pose.V, aligner.surface(X), true


def oracle_pull(mesh_a, mesh_b, truth_ab, faces, size, options, segment, names, patterns):
    """B aligned by the pairwise aligner as it runs (its own rigid start), then the parts whose
    skeleton segment names contain one of ``patterns`` pulled onto their true places (the rest of
    the surface held where the alignment left it), then fitted again from there: does a part put
    in its place stay there? Returns {key: % of the model size} and the pulled vertices' count."""
    import numpy as np

    from engine.align.evaluation import nearest_template_vertices
    from engine.align.limb_graft import carry

    aligner, target, V, true = _pair_aligner(mesh_a, mesh_b, truth_ab, faces, options)
    owner = segment[nearest_template_vertices(V, truth_ab[0], faces)]
    chosen = [k for k, name in enumerate(names) if any(p in name for p in patterns)]
    part = np.isin(owner, chosen)
    result = aligner.align(aligner.V_tet, target)
    X = carry(aligner, result.X, np.where(part[:, None], true, result.V))
    pulled = aligner.surface(X)
    refit = aligner._fit(X, target)
    out = {}
    for key, W in (("as_aligned", result.V), ("pulled", pulled), ("pulled_fit", refit.V)):
        error = 100.0 * np.linalg.norm(W - true, axis=1) / size
        out[f"{key}_pct"] = round(float(error.mean()), 3)
        out[f"{key}_parts_pct"] = round(float(error[part].mean()), 3) if part.any() else 0.0
    return out, int(part.sum())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", nargs="?", type=Path, help="a dataset with ground truth (morphspace synth)")
    parser.add_argument("--sequence", default="dance")
    parser.add_argument("--pairs", default="", help="A:B frame pairs, comma separated (B aligned from A)")
    parser.add_argument("--every", type=int, default=0, help="also the pairs a:a+1 for a = 10, 10 + K, ...")
    parser.add_argument("--oracle-rigid", action="store_true",
                        help="also align each pair from its true rigid placement and from its true pose")
    parser.add_argument("--option", dest="options", action="append", default=None, metavar="NAME=VALUE",
                        help="an AlignmentOptions field (repeatable)")
    parser.add_argument("--segments", type=int, default=0, metavar="K",
                        help="also list each pair's K worst skeleton segments (from the dataset's rig)")
    parser.add_argument("--oracle-pull", default="", metavar="NAMES",
                        help="also pull the parts whose skeleton segment names contain one of these (comma "
                             "separated, e.g. arm,hand) onto their true places after the alignment, and fit again")
    parser.add_argument("--tiny", action="store_true", help="the test suite's smoke run (no dataset)")
    parser.add_argument("--out", type=Path, help="write the JSON here too")
    args = parse_arguments(parser, argv, TINY)
    if not args.tiny and args.dataset is None:
        parser.error("a dataset is needed (or --tiny)")
    import numpy as np

    from engine.align import align_captures, score_alignment
    from engine.align.breakdown import part_labels

    options, changes = parse_options(args.options)
    if args.tiny:
        frames, truth, faces, size = load_frames(None, "run", 0, 4, True)
    else:
        frames, truth, faces, size = load_frames(args.dataset, args.sequence, 0, 10 ** 6, False)
    pairs = parse_pairs(args.pairs, args.every, len(frames))
    if not pairs:
        parser.error("no pairs: give --pairs or --every")
    parts = None if args.tiny else part_counts(args.dataset, False)
    patterns = [p for p in args.oracle_pull.split(",") if p]
    segment, joint_names = (template_segments(args.dataset, args.tiny) if args.segments > 0 or patterns
                            else (None, None))
    names = list(parts) if parts else ["all"]
    load_before = os.getloadavg()
    cpu_started = time.process_time()
    rows = []
    for a, b in pairs:
        two, truth_ab = [frames[a], frames[b]], truth[[a, b]]
        run = align_captures(two, np.array([2]), method="tree", root=0, workers=1, options=options, repair=False)
        errors, _ = score_alignment(run.aligned.vertices, 0, run.aligned.root_vertices, truth_ab, faces, size)
        root_vertices = run.aligned.root_vertices
        labels = (part_labels(root_vertices, truth_ab[0], faces, parts) if parts
                  else np.zeros(len(root_vertices), dtype=np.int64))
        pct = 100.0 * errors[1] / size
        row = {"pair": [a, b], "mean_pct": round(float(pct.mean()), 3),
               "parts_pct": {name: round(float(pct[labels == k].mean()), 3) for k, name in enumerate(names)
                             if np.any(labels == k)}}
        if args.segments > 0:
            row["worst_segments_pct"] = worst_segments(pct, root_vertices, truth_ab[0], faces, segment, joint_names,
                                                       args.segments)
        if args.oracle_rigid:
            aligned, placed, from_pose, pose, true = oracle_step(frames[a], frames[b], truth_ab, faces, options)
            for key, W in (("oracle_rigid_pct", aligned), ("placement_alone_pct", placed),
                           ("oracle_pose_pct", from_pose), ("true_pose_pct", pose)):
                row[key] = round(float(100.0 * np.linalg.norm(W - true, axis=1).mean() / size), 3)
        if patterns:
            row["oracle_pull"], row["oracle_pull_vertices"] = oracle_pull(
                frames[a], frames[b], truth_ab, faces, size, options, segment, joint_names, patterns)
        rows.append(row)
        extra = (f", from the true rigid placement {row['oracle_rigid_pct']:.2f}% (that placement alone "
                 f"{row['placement_alone_pct']:.2f}%), from the true pose {row['oracle_pose_pct']:.2f}% (that "
                 f"pose alone {row['true_pose_pct']:.2f}%)" if args.oracle_rigid else "")
        worst = ("; worst segments " + ", ".join(f"{k} {v:.1f}%" for k, v in row["worst_segments_pct"].items())
                 if args.segments > 0 else "")
        pull = row.get("oracle_pull")
        pulled = (f"; {'/'.join(patterns)} ({row['oracle_pull_vertices']} vertices) pulled: aligned directly "
                  f"{pull['as_aligned_pct']:.2f}% (those parts {pull['as_aligned_parts_pct']:.1f}%), pulled "
                  f"{pull['pulled_pct']:.2f}% ({pull['pulled_parts_pct']:.1f}%), then the fit "
                  f"{pull['pulled_fit_pct']:.2f}% ({pull['pulled_fit_parts_pct']:.1f}%)" if pull else "")
        print(f"{a} -> {b}: {row['mean_pct']:.2f}%{extra}; " + ", ".join(f"{k} {v:.2f}%" for k, v in row["parts_pct"].items())
              + worst + pulled, flush=True)
    cpu = time.process_time() - cpu_started
    means = [row["mean_pct"] for row in rows]
    record = {"dataset": "tiny" if args.tiny else str(args.dataset), "sequence": "run" if args.tiny else args.sequence,
              "options": changes, "pairs": rows, "mean_pct": round(float(np.mean(means)), 3),
              "median_pct": round(float(np.median(means)), 3), "cpu_seconds": round(cpu, 2),
              "load_average_before": [round(x, 2) for x in load_before],
              "load_average_after": [round(x, 2) for x in os.getloadavg()], "python": platform.python_version()}
    if args.oracle_rigid:
        for key in ("oracle_rigid", "oracle_pose"):
            record[f"{key}_mean_pct"] = round(float(np.mean([row[f"{key}_pct"] for row in rows])), 3)
    if patterns:
        record["oracle_pull_parts"] = patterns
        for key in ("as_aligned", "pulled", "pulled_fit"):
            record[f"oracle_pull_{key}_mean_pct"] = round(float(np.mean([row["oracle_pull"][f"{key}_pct"]
                                                                         for row in rows])), 3)
    print(f"{len(rows)} single steps: mean {record['mean_pct']:.2f}%, median {record['median_pct']:.2f}% of the "
          f"model size" + (f"; from the true rigid placement: mean {record['oracle_rigid_mean_pct']:.2f}%; from the "
                           f"true pose: mean {record['oracle_pose_mean_pct']:.2f}%" if args.oracle_rigid else "")
          + (f"; {'/'.join(patterns)} pulled onto the truth, then the fit: mean "
             f"{record['oracle_pull_pulled_fit_mean_pct']:.2f}% (aligned directly "
             f"{record['oracle_pull_as_aligned_mean_pct']:.2f}%)" if patterns else "")
          + f"; {cpu:.1f} CPU s", flush=True)
    emit(record, args.out)


if __name__ == "__main__":
    sys.exit(main())

"""Frame-to-frame alignment with and without a momentum start, against the ground truth.

From one root frame, every following frame of one sequence is aligned from the one before it
(``PairwiseAligner.align``, the tree's own step), starting from the previous pose moved on by
``momentum`` times the last step (``engine.align.propagation.MOMENTUM`` in the pipeline; 0 is the
previous pose itself). Each frame is scored against the generator's ground truth (mean error over
the root's vertices, % of the model size), so a fast limb that the aligner loses shows up as the
frames after it. Prints a line per momentum and one JSON object (with the load average, since the
machine may be shared).

    .venv/bin/python benchmarks/align_momentum.py /tmp/studio --sequence dance --root 105 --frames 15 \\
        [--momentum 0 0.5 1] [--out benchmarks/results/align_momentum.json]
    .venv/bin/python benchmarks/align_momentum.py --tiny --out /tmp/align_momentum.json

``--tiny`` (the test suite's smoke run) needs no dataset: a run of the generator's 1,000-vertex body
at 15 fps from its frame 2, 4 frames, small alignment settings; ``--out`` is required with it.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

from _tiny import TINY_FPS, TINY_VERTICES, emit, parse_arguments

TINY = {"root": 2, "frames": 4, "patches": 8, "levels": 1}


def load_sequence(dataset, sequence, tiny):
    """(frames as (V, F, colours or None) in metres +Y up, ground truth (T, m, 3) in metres, template faces)."""
    import numpy as np

    if tiny:
        from engine.synthetic import SequenceSpec, build_body, generate_sequence_data

        body = build_body(TINY_VERTICES)
        data = generate_sequence_data(body, SequenceSpec("run", "gait", {"speed": 3.0, "cycles": 1.0}),
                                      fps=TINY_FPS, seed=1)
        return [(V, F, None) for V, F, _ in data["unstructured"]], data["truth"]["template_positions"], body.F
    from engine.mesh_io import read_frames, read_mesh
    from engine.mesh_io.dataset import load_capture_truth
    from engine.mesh_io.units import resolve_convention, to_metres_y_up

    frames = read_frames(Path(dataset) / "sequences" / sequence / "unstructured")
    convention = resolve_convention([f.vertices for f in frames])
    meshes = [(to_metres_y_up(f.vertices, convention.units, convention.up), f.faces,
               None if f.colors is None else np.asarray(f.colors)) for f in frames]
    truth = to_metres_y_up(load_capture_truth(Path(dataset), sequence)["template_positions"],
                           convention.units, convention.up)
    return meshes, truth, read_mesh(Path(dataset) / "template" / "body.obj").faces


def chain(meshes, truth, faces, root, count, momentum, options):
    """Mean error (% of the model size) of each of ``count`` frames after ``root``, and CPU seconds."""
    import numpy as np

    from engine.align import PairwiseAligner, TargetSurface, score_alignment
    from engine.align.captures import colours_carry_texture
    from engine.surface import main_components, model_size

    V, F, C = meshes[root]
    V, F, kept = main_components(V, F)
    colours = C is not None and colours_carry_texture(V, F)
    aligner = PairwiseAligner(V, F, C[kept] if colours else None, options=options)
    size = model_size(truth[root])
    previous, pose, errors = None, aligner.V_tet, []
    started = time.process_time()
    for frame in range(root + 1, root + 1 + count):
        start = pose if previous is None else pose + momentum * (pose - previous)
        Vt, Ft, C = meshes[frame]
        Vt, Ft, kept = main_components(Vt, Ft)
        result = aligner.align(start, TargetSurface(Vt, Ft, C[kept] if colours else None))
        previous, pose = pose, result.X
        error, _ = score_alignment(np.stack([V, result.V]), 0, V, truth[[root, frame]], faces, size)
        errors.append(100.0 * float(error[1].mean()) / size)
    return errors, time.process_time() - started


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", nargs="?", help="a dataset with ground truth (morphspace synth)")
    parser.add_argument("--sequence", default="dance")
    parser.add_argument("--root", type=int, default=105, help="the frame aligned from (default 105)")
    parser.add_argument("--frames", type=int, default=15, help="frames aligned after it (default 15)")
    parser.add_argument("--momentum", type=float, nargs="+", default=[0.0, 0.5, 1.0])
    parser.add_argument("--patches", type=int, default=None, help="AlignmentOptions.patches (default: its own)")
    parser.add_argument("--levels", type=int, default=None, help="AlignmentOptions.levels (default: its own)")
    parser.add_argument("--tiny", action="store_true", help="the test suite's smoke run (no dataset)")
    parser.add_argument("--out", type=Path, help="write the JSON here too")
    args = parse_arguments(parser, argv, TINY)
    if not args.tiny and args.dataset is None:
        parser.error("a dataset is needed (or --tiny)")
    from dataclasses import replace

    from engine.align import AlignmentOptions
    from engine.align.captures import COLOUR_WEIGHT

    options = AlignmentOptions(colour_weight=COLOUR_WEIGHT)
    if args.patches is not None:
        options = replace(options, patches=args.patches)
    if args.levels is not None:
        options = replace(options, levels=args.levels, rounds=options.rounds[:args.levels])
    meshes, truth, faces = load_sequence(args.dataset, args.sequence, args.tiny)
    if not 0 <= args.root < len(meshes) - args.frames:
        parser.error(f"--root {args.root} with --frames {args.frames} runs past the sequence's {len(meshes)} frames")
    record = {"dataset": "tiny" if args.tiny else str(args.dataset), "sequence": "run" if args.tiny else args.sequence,
              "root": args.root, "frames": args.frames, "runs": [],
              "load_average": round(os.getloadavg()[0], 2), "python": platform.python_version()}
    for momentum in args.momentum:
        errors, cpu = chain(meshes, truth, faces, args.root, args.frames, momentum, options)
        record["runs"].append({"momentum": momentum, "errors_pct": [round(e, 3) for e in errors],
                               "mean_pct": round(sum(errors) / len(errors), 3), "last_pct": round(errors[-1], 3),
                               "cpu_seconds_per_frame": round(cpu / len(errors), 3)})
        print(f"momentum {momentum:g}: mean {record['runs'][-1]['mean_pct']:.2f}%, last frame {errors[-1]:.2f}% "
              f"({' '.join(f'{e:.2f}' for e in errors)}), {cpu / len(errors):.2f} CPU s per frame", flush=True)
    emit(record, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How far the hybrid blend is from the exact non-linear blend over a space's whole parameter sheet.

``morphspace build`` bounds the hybrid at its layout's test weights (33 along a chain, 17 x 17 on
a fan or grid) and checks it halfway between them. This samples the sheet more densely still,
every phase sample at every weight, and reports the worst distance, where it is and how many
weights are over the space's epsilon, beside what the build itself recorded::

    .venv/bin/python benchmarks/hybrid_sheet.py data/spaces/locomotion.mspace --per-axis 65
    .venv/bin/python benchmarks/hybrid_sheet.py --tiny --out /tmp/hybrid_sheet.json   # about 15 s

``--per-axis`` must hold the build's own test weights, so the figures tell them from the weights
between: along a chain (33 test weights) 33, 65, 97, ...; on a sheet (17 per axis) 17, 33, 49, ...;
``--build-per-axis`` names another test grid a space was built with.

``--tiny`` (the test suite's smoke run) builds a small grid space first: four jumps (low / high,
short / long) of a 1,000-vertex body at 15 fps, 8 phase samples, its bound tested on a 5 x 5 grid
and checked between (``--build-per-axis 5`` says so to the figures).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _tiny import TINY_FPS, TINY_VERTICES, emit, parse_arguments  # noqa: E402

TINY_JUMPS = (("jump_low_short", 0.3, 0.3), ("jump_low_long", 0.3, 1.2),
              ("jump_high_short", 0.55, 0.3), ("jump_high_long", 0.55, 1.2))


def build_tiny_jump_space(path, per_axis):
    """Four jumps in a grid layout (height x distance), epsilon 5 mm, 8 phase samples, the hybrid
    tested at ``per_axis`` x ``per_axis`` weights and checked between them."""
    from engine.motion_space import SourceClip, build_motion_space
    from engine.parameters.sheet import between_weights, sheet_weights
    from engine.parameters import Layout
    from engine.synthetic import SequenceSpec, build_body, generate_sequence_data

    body = build_body(TINY_VERTICES)
    clips = []
    for name, height, distance in TINY_JUMPS:
        data = generate_sequence_data(body, SequenceSpec(name, "jump", {"height": height, "distance": distance}),
                                      fps=TINY_FPS, unstructured=False)
        clips.append(SourceClip(name, data["vertices"], TINY_FPS, False))
    layout = Layout("grid", 4, corners=(0, 1, 2, 3))
    build_motion_space(path, clips, body.F, name=path.stem, n_phases=8, epsilon=0.005, rest=body.V,
                       parameters={"layout": layout, "names": ["jump_height", "jump_distance"]},
                       hybrid_options={"test_weights": sheet_weights(layout, per_axis),
                                       "check_weights": between_weights(layout, per_axis)})


def sheet_errors(path, per_axis, build_per_axis=None):
    """The space's hybrid against its non-linear blend at ``per_axis`` weights per layout axis
    (``build_per_axis``: the build's test weights per axis, default ``sheet_resolution``)."""
    from engine.blend import phase_of_sample
    from engine.motion_space import MotionSpace
    from engine.parameters.sheet import sheet_coordinates, sheet_resolution, sheet_weights

    with MotionSpace.open(path) as space:
        pmap = space.parameter_map
        if pmap is None:
            raise SystemExit(f"{path}: the space has no parameter layout, so it has no sheet to sample")
        layout = pmap.layout
        u = sheet_coordinates(layout, per_axis)
        weights = sheet_weights(layout, per_axis)
        hybrid, nonlinear = space.blender("hybrid"), space.blender("nonlinear")
        phases = [phase_of_sample(p, space.n_phases, space.cyclic) for p in range(space.n_phases)]
        started, cpu = time.perf_counter(), time.process_time()
        errors = np.array([max(float(np.linalg.norm(hybrid.blend(w, t).astype(np.float64)
                                                    - nonlinear.blend(w, t).astype(np.float64), axis=1).max())
                               for t in phases) for w in weights])
        seconds, cpu = time.perf_counter() - started, time.process_time() - cpu
        # Which of the sampled weights the build tested (on its own grid) and which lie between
        test_axis = (build_per_axis or sheet_resolution(layout)) - 1
        if (per_axis - 1) % test_axis:
            raise SystemExit(f"{path}: --per-axis {per_axis} does not hold the build's {test_axis + 1} test "
                             f"weights per axis: use {test_axis} k + 1 weights (e.g. {2 * test_axis + 1}), or give "
                             "--build-per-axis for a space built with other test weights")
        on_grid = np.all(np.abs(u * test_axis - np.round(u * test_axis)) < 1e-9, axis=1)
        epsilon = float(space.metadata["epsilon"])
        worst = int(np.argmax(errors))
        built = space.metadata["hybrid"]
        return {
            "space": str(path), "layout": layout.kind, "sources": space.n_sources, "vertices": space.n_vertices,
            "phases": space.n_phases, "epsilon_mm": 1000 * epsilon, "per_axis": per_axis, "weights": len(weights),
            "max_error_mm": round(1000 * float(errors.max()), 3),
            "worst_at": {"u": [round(float(x), 4) for x in u[worst]],
                         "weights": [round(float(x), 4) for x in weights[worst]]},
            "weights_over_epsilon": int((errors > epsilon).sum()),
            "max_error_test_weights_mm": round(1000 * float(errors[on_grid].max(initial=0.0)), 3),
            "max_error_between_mm": round(1000 * float(errors[~on_grid].max(initial=0.0)), 3),
            "build": {"references": built["references"], "max_test_error_mm": round(1000 * built["max_test_error"], 3),
                      "check_points": built.get("check_points", 0),
                      "max_check_error_mm": (None if built.get("max_check_error") is None
                                             else round(1000 * built["max_check_error"], 3)),
                      "check_added": built.get("check_added", 0),
                      "corrections_share_of_sources": round(built["correction_bytes"] / built["source_bytes"], 4)},
            "seconds": round(seconds, 2), "cpu_seconds": round(cpu, 2),
        }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("spaces", nargs="*", type=Path, help="motion-space files with a parameter layout")
    parser.add_argument("--per-axis", type=int, default=65,
                        help="weights per layout axis (default 65: 4 times the build's test spacing on a "
                             "17 x 17 sheet, twice on a 33-weight chain)")
    parser.add_argument("--build-per-axis", type=int,
                        help="the build's test weights per axis, if not the default (33 on a chain, 17 on a sheet)")
    parser.add_argument("--tiny", action="store_true", help="smoke run: a small grid space, built first; needs --out")
    parser.add_argument("--out", type=Path, help="also write the figures to this JSON file")
    args = parse_arguments(parser, argv, {"per_axis": 17, "build_per_axis": 5})
    if args.per_axis < 2:
        parser.error("--per-axis must be at least 2")
    rows = []
    with tempfile.TemporaryDirectory() as work:
        spaces = list(args.spaces)
        if args.tiny:
            if spaces:
                parser.error("--tiny builds its own space: give no motion-space files with it")
            spaces = [Path(work) / "tiny_jumps.mspace"]
            build_tiny_jump_space(spaces[0], args.build_per_axis)
        if not spaces:
            parser.error("give at least one motion-space file (or --tiny)")
        for path in spaces:
            row = sheet_errors(path, args.per_axis, args.build_per_axis)
            rows.append(row)
            print(f"{path.name}: {row['layout']} layout, {row['weights']} weights x {row['phases']} phases: "
                  f"max {row['max_error_mm']:.2f} mm at u = {row['worst_at']['u']} (epsilon {row['epsilon_mm']:g} mm; "
                  f"{row['weights_over_epsilon']} weights over it); the build's test weights "
                  f"{row['max_error_test_weights_mm']:.2f} mm, between them {row['max_error_between_mm']:.2f} mm",
                  file=sys.stderr)
    emit(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

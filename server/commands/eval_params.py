"""Accuracy of a motion space's parameter map: realised vs requested over the reachable domain.

Requests on a grid of the parameters' domain are turned into blend weights by the map, and the
parameters are measured again on the blend itself. Reports max and mean error in units and in
% of each parameter's range (the target is 5%). Example:

    morphspace eval-params data/spaces/locomotion.mspace --json
"""

from __future__ import annotations

import json
from pathlib import Path

from engine.motion_space import MotionSpace
from engine.parameters import accuracy_report

MIN_PER_AXIS, MAX_PER_AXIS = 2, 201
MAX_REQUESTS = 10_000  # per_axis ** parameters: each request measures a blend at every phase


def add_arguments(parser):
    parser.add_argument("space", type=Path, help="a .mspace file with parameters")
    parser.add_argument("--mode", choices=("linear", "hybrid", "nonlinear"), default="hybrid",
                        help="blend used to measure the realised parameters (default hybrid)")
    parser.add_argument("--per-axis", type=int, help=f"requests per parameter axis, {MIN_PER_AXIS} to {MAX_PER_AXIS} "
                        f"and at most {MAX_REQUESTS} in all (default 41 for one parameter, else 9)")
    parser.add_argument("--json", action="store_true")


def run(args):
    if args.per_axis is not None and not MIN_PER_AXIS <= args.per_axis <= MAX_PER_AXIS:
        raise ValueError(f"--per-axis must be between {MIN_PER_AXIS} and {MAX_PER_AXIS}, got {args.per_axis}")
    space = MotionSpace.open(args.space)
    if space.parameter_map is None:
        raise ValueError(f"{args.space}: the space has no parameter map (build it from a spec with parameters)")
    k = len(space.parameter_map.names)
    if args.per_axis is not None and args.per_axis ** k > MAX_REQUESTS:
        raise ValueError(f"--per-axis {args.per_axis} with {k} parameters is {args.per_axis ** k} requests; at most "
                         f"{MAX_REQUESTS} (--per-axis {int(MAX_REQUESTS ** (1 / k) + 1e-9)} or less)")
    report = accuracy_report(space, blend_mode=args.mode, per_axis=args.per_axis)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{space.name}: {report['requests']} requests on a grid of the domain, {report['unreachable']} "
          f"outside the reachable part, measured on {args.mode} blends")
    for name, r in report["parameters"].items():
        lo, hi = r["domain"]
        print(f"  {name:<14} domain {lo:.3g}..{hi:.3g} {r['unit']}: max error {r['max_error']:.4g} {r['unit']} "
              f"({r['max_error_percent_of_range']:.2f}% of range), mean {r['mean_error']:.4g} {r['unit']} "
              f"({r['mean_error_percent_of_range']:.2f}%)")
    return 0

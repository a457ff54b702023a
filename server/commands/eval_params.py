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


def add_arguments(parser):
    parser.add_argument("space", type=Path, help="a .mspace file with parameters")
    parser.add_argument("--mode", choices=("linear", "hybrid", "nonlinear"), default="hybrid",
                        help="blend used to measure the realised parameters (default hybrid)")
    parser.add_argument("--per-axis", type=int, help="requests per parameter axis (default 41 or 9)")
    parser.add_argument("--json", action="store_true")


def run(args):
    space = MotionSpace.open(args.space)
    report = accuracy_report(space, blend_mode=args.mode, per_axis=args.per_axis)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{space.name}: {report['requests']} requests on a grid of the domain, {report['unreachable']} "
          f"outside the reachable part, measured on {args.mode} blends")
    for name, r in report["parameters"].items():
        lo, hi = r["domain"]
        print(f"  {name:<14} domain {lo:.3g}..{hi:.3g} {r['unit']}: max error {r['max_error']:.4g} "
              f"({r['max_error_percent_of_range']:.2f}% of range), mean {r['mean_error']:.4g} "
              f"({r['mean_error_percent_of_range']:.2f}%)")
    return 0

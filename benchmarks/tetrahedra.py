"""Tetrahedralisation time and determinism against surface resolution (issue 12, deliverable 4).

For each surface resolution: a synthetic body surface (the procedural body at 10k vertices,
then midpoint-subdivided for larger counts, so the shape stays the same), tetrahedralised
``--repeat`` times with ``engine.tetmesh.tetrahedralize`` (the voxel lattice). Prints the median
time, the tet counts and whether every run gave the same bytes; writes JSON.

    .venv/bin/python benchmarks/tetrahedra.py [--vertices 10000 40000] [--repeat 5] [--out results.json]
    .venv/bin/python benchmarks/tetrahedra.py --tiny --out /tmp/tetrahedra.json   # a few seconds
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import time
from pathlib import Path

import numpy as np

from _tiny import parse_arguments
from engine.synthetic import build_body
from engine.tetmesh import tetrahedralize


def body_surface(n_vertices):
    """(V, F) of the procedural body with at least about ``n_vertices`` vertices."""
    body = build_body(min(n_vertices, 10000))
    V, F = body.V, body.F
    while len(V) < 0.9 * n_vertices:
        import trimesh

        V, F = trimesh.remesh.subdivide(V, F)
    return np.asarray(V), np.asarray(F)


def run_one(n_vertices, repeat):
    V, F = body_surface(n_vertices)
    times, digests = [], set()
    for _ in range(repeat):
        started = time.perf_counter()
        V_tet, T = tetrahedralize(V, F)
        times.append(time.perf_counter() - started)
        digests.add(hashlib.sha256(V_tet.tobytes() + T.tobytes()).hexdigest())
    return {"surface_vertices": int(len(V)), "tet_vertices": int(len(V_tet)), "tets": int(len(T)),
            "median_s": statistics.median(times), "max_s": max(times), "runs": repeat,
            "identical": len(digests) == 1}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, nargs="+", default=[10000, 40000])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/tetrahedra.json)")
    parser.add_argument("--tiny", action="store_true", help="1,000 vertices, 2 runs (needs --out)")
    args = parse_arguments(parser, argv, {"vertices": [1000], "repeat": 2})
    out = args.out or Path(__file__).parent / "results" / "tetrahedra.json"
    rows = []
    for n in args.vertices:
        row = run_one(n, args.repeat)
        rows.append(row)
        print(f"{row['surface_vertices']:>7} surface vertices: {row['tets']} tets on {row['tet_vertices']} vertices, "
              f"median {row['median_s']:.3f} s (max {row['max_s']:.3f}) over {row['runs']} runs, "
              f"{'identical' if row['identical'] else 'DIFFERENT'} bytes")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

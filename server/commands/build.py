"""Build a motion space from N consistent-topology source sequences.

Each --source is a sequence directory of a capture dataset (``sequences/<name>``: its meta.json
gives the frame rate and whether it is cyclic) or any directory or zip of per-frame meshes
(non-cyclic unless --cyclic is given). Cycle lengths, key poses and events are found on the
meshes. Example:

    morphspace build --source data/captures/demo/sequences/walk_slow \\
                     --source data/captures/demo/sequences/jog --out walk_jog.mspace
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from engine.mesh_io import read_mesh, read_sequence
from engine.motion_space import SourceClip, build_motion_space


def add_arguments(parser):
    parser.add_argument("--source", action="append", required=True, type=Path, metavar="DIR",
                        help="a source sequence (repeat for each source; at least 2)")
    parser.add_argument("--out", required=True, type=Path, help="output .mspace file")
    parser.add_argument("--name", help="space name (default: the output file's stem)")
    parser.add_argument("--epsilon-mm", type=float, default=5.0, help="hybrid error bound in mm (default 5)")
    parser.add_argument("--phases", type=int, help="phase samples (default: longest source's frames)")
    parser.add_argument("--rest", type=Path, help="rest-pose mesh to tetrahedralise (default: the "
                        "capture dataset's template/body.obj, else the first source's first frame)")
    parser.add_argument("--fps", type=float, default=30.0, help="frame rate of sources without meta.json")
    parser.add_argument("--cyclic", action="store_true", help="sources without meta.json are cyclic")
    parser.add_argument("--force", action="store_true", help="replace an existing output file")


def load_source(directory, *, fps, cyclic):
    """SourceClip from a capture-dataset sequence directory or a directory/zip of frames."""
    directory = Path(directory)
    meta_path = directory / "meta.json"
    if meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        sequence = read_sequence(directory / "consistent")
        return SourceClip(name=meta["name"], vertices=sequence.vertices, fps=float(meta["fps"]),
                          cyclic=bool(meta["cyclic"])), sequence.faces
    sequence = read_sequence(directory)
    return SourceClip(name=directory.stem, vertices=sequence.vertices, fps=fps, cyclic=cyclic), sequence.faces


def run(args):
    if len(args.source) < 2:
        raise ValueError("a motion space needs at least 2 --source sequences")
    if args.out.exists() and not args.force:
        raise FileExistsError(f"{args.out} already exists; pass --force to replace it")
    if args.epsilon_mm <= 0:
        raise ValueError(f"--epsilon-mm must be > 0, got {args.epsilon_mm}")
    clips, faces = [], None
    for directory in args.source:
        clip, F = load_source(directory, fps=args.fps, cyclic=args.cyclic)
        if faces is not None and (F.shape != faces.shape or not np.array_equal(F, faces)):
            raise ValueError(f"{directory}: its faces differ from {args.source[0]}'s; "
                             "all sources need the same mesh structure")
        faces = F
        clips.append(clip)
    rest = None
    rest_path = args.rest
    if rest_path is None:
        candidate = args.source[0].parent.parent / "template" / "body.obj"
        rest_path = candidate if candidate.is_file() else None
    if rest_path is not None:
        mesh = read_mesh(rest_path)
        if mesh.vertices.shape != clips[0].vertices.shape[1:] or not np.array_equal(mesh.faces, faces):
            raise ValueError(f"{rest_path}: the rest mesh must have the sources' vertices and faces")
        rest = mesh.vertices

    bars = {}

    def progress(stage, done, total):
        if stage not in bars:
            for bar in bars.values():
                bar.close()
            bars.clear()
            bars[stage] = tqdm(total=total or None, desc=stage, unit="step", dynamic_ncols=True, mininterval=0.5)
        bar = bars[stage]
        if total:
            bar.total = total
        bar.n = done
        bar.refresh()

    started = time.perf_counter()
    report = build_motion_space(args.out, clips, faces, name=args.name or args.out.stem, n_phases=args.phases,
                                epsilon=args.epsilon_mm / 1000.0, rest=rest, progress=progress)
    for bar in bars.values():
        bar.close()
    hybrid = report["hybrid"]
    print(f"wrote {args.out}: {report['n_sources']} sources x {report['n_phases']} phases, "
          f"{report['n_vertices']} vertices, {report['n_tets']} tets, in {time.perf_counter() - started:.1f} s")
    print(f"  hybrid: {hybrid['references']} references, {hybrid['leaves']} cells, max test error "
          f"{hybrid['max_test_error'] * 1000:.2f} mm (epsilon {args.epsilon_mm:g} mm), corrections "
          f"{hybrid['correction_bytes'] / 1e6:.2f} MB = {100 * hybrid['correction_bytes'] / hybrid['source_bytes']:.1f}% "
          f"of the sources")
    return 0

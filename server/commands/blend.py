"""Blend two or more same-topology meshes: linear, exact non-linear or hybrid.

The way to try morphspace's blending on your own meshes. Non-linear and hybrid blending
tetrahedralise the first mesh (or --rest; holes are capped). The meshes' units and up axis are
detected (or given with --units/--up), the blend is made in metres with +Y up, and the output is
written back in the inputs' units and axes, with the inputs' vertex colours mixed by the weights
when every input has colours. Progress bars on stderr follow the stages: read,
tetrahedralise, decompose, solve, hybrid (hybrid mode or --compare), write. Example:

    morphspace blend walk.obj run.obj --weights 0.5 0.5 --mode nonlinear --out half.obj
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from engine.blend import (
    FrameDecomposer,
    HybridBlender,
    LinearBlender,
    NonlinearBlender,
    PhasedNonlinearBlender,
    VolumetricEmbedding,
    build_hybrid,
    decompose_frames,
)
from engine.mesh_io import read_mesh, write_mesh
from engine.mesh_io.units import from_metres_y_up, to_metres_y_up
from engine.surface import model_size
from server.commands.build import EPSILON_MM
from server.progress import StageBars
from server.units import add_units_arguments, length_text, meshes_to_metres, say_conventions


MAX_SIZE_RATIO = 10.0  # inputs whose sizes differ more than this are in different units


def add_arguments(parser):
    parser.add_argument("meshes", nargs="+", type=Path, help="two or more meshes with the same topology")
    parser.add_argument("--weights", nargs="+", type=float, required=True,
                        help="one non-negative weight per mesh (normalised to sum 1)")
    parser.add_argument("--mode", choices=("linear", "nonlinear", "hybrid"), default="nonlinear")
    parser.add_argument("--out", type=Path, required=True, help="output mesh (.obj, .ply or .off)")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file (never one of the inputs)")
    parser.add_argument("--rest", type=Path, help="rest shape to tetrahedralise (default: the first mesh)")
    parser.add_argument("--epsilon-mm", type=float, default=5.0, help="hybrid error bound in mm (default 5)")
    parser.add_argument("--compare", action="store_true",
                        help="also report linear and hybrid errors against the non-linear blend")
    add_units_arguments(parser)


def _load(paths, progress):
    meshes = []
    for k, path in enumerate(paths):
        progress("read", k, len(paths))
        meshes.append(read_mesh(path))
    progress("read", len(paths), len(paths))
    first = meshes[0]
    for path, mesh in zip(paths[1:], meshes[1:]):
        if len(mesh.vertices) != len(first.vertices):
            raise ValueError(f"{path} has {len(mesh.vertices)} vertices, {paths[0]} has {len(first.vertices)}; "
                             "blending needs meshes with the same topology")
        if len(mesh.faces) != len(first.faces):
            raise ValueError(f"{path} has {len(mesh.faces)} faces, {paths[0]} has {len(first.faces)}; "
                             "blending needs meshes with the same topology (the face count differs)")
        if not np.array_equal(mesh.faces, first.faces):
            face = int(np.flatnonzero((mesh.faces != first.faces).any(axis=1))[0])
            raise ValueError(f"{path}: face {face} is {tuple(mesh.faces[face].tolist())} but in {paths[0]} it is "
                             f"{tuple(first.faces[face].tolist())}; blending needs meshes with the same topology "
                             "(the connectivity differs)")
    sizes = [model_size(mesh.vertices) for mesh in meshes]
    for path, size in zip(paths, sizes):
        if not (np.isfinite(size) and size > 0):
            raise ValueError(f"{path}: model size must be positive and finite, got {size} (all its vertices at "
                             "one point): nothing to blend")
    big, small = int(np.argmax(sizes)), int(np.argmin(sizes))
    if sizes[big] > MAX_SIZE_RATIO * sizes[small]:  # one decision of units for all: the same units, or a mistake
        raise ValueError(f"{paths[big]} is {sizes[big] / sizes[small]:.0f} times the size of {paths[small]}: "
                         "blend meshes in the same units (convert one, e.g. from millimetres to metres)")
    return meshes


def run(args):
    if len(args.meshes) < 2:
        raise ValueError("give at least two meshes to blend")
    if len(args.weights) != len(args.meshes):
        raise ValueError(f"{len(args.meshes)} meshes need {len(args.meshes)} weights, got {len(args.weights)}")
    w = np.asarray(args.weights, dtype=np.float64)
    if not np.all(np.isfinite(w)) or np.any(w < 0) or w.max() <= 0:
        raise ValueError(f"weights must be finite, non-negative and not all zero, got {args.weights}")
    w = w / w.max()  # (then their sum cannot overflow: 1e308 and 1e308 blend half and half)
    if not (np.isfinite(args.epsilon_mm) and 0 < args.epsilon_mm <= EPSILON_MM[1]):  # (build's range)
        raise ValueError(f"--epsilon-mm must be above {EPSILON_MM[0]:g} and at most {EPSILON_MM[1]:g} (mm), "
                         f"got {args.epsilon_mm}")
    if args.out.is_dir():
        raise ValueError(f"--out {args.out} is a directory: name the output mesh file (.obj, .ply or .off)")
    if args.out.exists():  # (it replaced even one of its own inputs without a word; a docs-only user)
        if any(args.out.resolve() == Path(p).resolve() for p in [*args.meshes, args.rest] if p is not None):
            raise ValueError(f"--out {args.out} is one of the input meshes; name another file")
        if not args.force:
            raise ValueError(f"--out {args.out} exists; pass --force to replace it")
    from engine.mesh_io.mesh_file import writable_type

    try:   # before the meshes are read and blended
        writable_type(args.out)
    except ValueError as exc:
        raise ValueError(f"--out {exc}") from None
    bars = StageBars()
    try:
        (meshes, convention), result, elapsed = _blend(args, w, bars)
    finally:
        bars.close()
    N, n = len(meshes), len(meshes[0].vertices)
    print(f"wrote {args.out}: {args.mode} blend of {N} meshes ({n} vertices) with weights "
          f"{np.round(w / w.sum(), 4).tolist()} in {elapsed:.2f} s, in the inputs' units ({convention.units}, "
          f"up {convention.up_label})")
    if args.compare:
        # the model size the units line states: the median over the inputs (the first mesh's alone
        # said 1.70 m where that line said 1.35 m)
        size = float(np.median([model_size(mesh.vertices) for mesh in meshes]))
        for mode in ("linear", "hybrid"):
            error = np.linalg.norm(result[mode] - result["nonlinear"], axis=1)
            print(f"  {mode:<7} vs non-linear: max {length_text(error.max(), convention, size)}, "
                  f"mean {length_text(error.mean(), convention, size)}")
    return 0


def _blend(args, w, progress):
    """Read, blend and write; ``progress(stage, done, total)`` is told about each stage.

    Returns ((meshes, convention), result, seconds): the input meshes in metres, +Y up and what
    their files were in, the (n, 3) blends by mode computed on the way (metres, +Y up;
    ``result[args.mode]`` is the one written, converted back), and the seconds from the meshes
    read to the blend written."""
    meshes, convention = meshes_to_metres(_load(args.meshes, progress), args.units, args.up)
    # tqdm.write: the line goes above the progress bar instead of onto its line
    say_conventions([convention], ["the meshes"], lambda line: tqdm.write(f"morphspace blend: {line}", file=sys.stderr))
    faces = meshes[0].faces
    sources = np.stack([m.vertices for m in meshes])[None].astype(np.float32)  # (P=1, N, n, 3)
    N, n = sources.shape[1:3]
    linear = LinearBlender(sources, cyclic=True)
    started = time.perf_counter()
    result = {}
    if args.mode == "linear" and not args.compare:
        progress("solve", 0, 1)
        result["linear"] = linear.blend(w, 0.0)
        progress("solve", 1, 1)
    else:
        rest = meshes[0].vertices
        if args.rest is not None:
            rest_mesh = read_mesh(args.rest)
            if rest_mesh.vertices.shape != rest.shape or not np.array_equal(rest_mesh.faces, faces):
                raise ValueError(f"{args.rest}: the rest mesh must have the same topology as the inputs")
            rest = to_metres_y_up(rest_mesh.vertices, convention.units, convention.up)  # as the inputs
        progress("tetrahedralise", 0, 1)
        try:
            embedding = VolumetricEmbedding.from_surface(rest, faces)
        except ValueError as exc:
            raise ValueError(f"{args.rest or args.meshes[0]}: cannot fill this surface with tetrahedra for "
                             f"non-linear blending ({exc}); use --mode linear") from None
        progress("tetrahedralise", 1, 1)
        frames = sources[0]
        progress("decompose", 0, N)
        try:
            q, s, d = decompose_frames(FrameDecomposer(embedding), frames,
                                       progress=lambda done, total: progress("decompose", done, total))
            progress("solve", 0, 1)
            nonlinear = PhasedNonlinearBlender(NonlinearBlender(embedding, q, s, d, frames), 1, N, cyclic=True)
        except ValueError as exc:
            raise ValueError(f"{args.rest or args.meshes[0]}: cannot blend this surface non-linearly ({exc}); "
                             f"use --mode linear") from None
        result["nonlinear"] = nonlinear.blend(w, 0.0)
        result["linear"] = linear.blend(w, 0.0)
        progress("solve", 1, 1)
        if args.mode == "hybrid" or args.compare:
            progress("hybrid", 0, 1)
            tree, corrections, report = build_hybrid(
                linear.blend_all_phases, nonlinear.blend_all_phases, N, 1, n, epsilon=args.epsilon_mm / 1000.0,
                progress=lambda message, done, total: progress("hybrid", done, total))
            result["hybrid"] = HybridBlender(sources, tree, corrections, cyclic=True).blend(w, 0.0)
            progress("hybrid", 1, 1)
    progress("write", 0, 1)
    colours = None  # the inputs' vertex colours mixed by the weights, when every input has them
    if all(m.colors is not None for m in meshes):
        colours = np.clip(np.einsum("k,kic->ic", w / w.sum(), np.stack([m.colors for m in meshes])), 0.0, 1.0)
    write_mesh(args.out, from_metres_y_up(np.asarray(result[args.mode], dtype=np.float64), convention.units,
                                          convention.up), faces, colours)
    progress("write", 1, 1)
    return (meshes, convention), result, time.perf_counter() - started

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
from engine.mesh_io import Mesh, read_mesh, write_mesh, write_ply
from engine.mesh_io.mesh_file import writable_type
from engine.mesh_io.units import from_metres_y_up, to_metres_y_up
from engine.surface import model_size
from server.commands.build import EPSILON_MM
from server.progress import StageBars
from server.units import add_units_arguments, length_text, meshes_to_metres, say_conventions


MAX_SIZE_RATIO = 10.0  # inputs whose sizes differ more than this are in different units
FLOAT32_REACH = 16.0   # model sizes from the origin beyond which a PLY output is written in float64


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


def _write(path, V, F, colours, size):
    """``write_mesh``, except that a PLY far from its origin is written in float64: float32 (PLY's
    convention) holds a coordinate to 1 part in 16.7 million, so beyond ``FLOAT32_REACH`` model
    sizes from the origin (survey coordinates) it would lose more than a millionth of the size."""
    if writable_type(path) == "ply" and np.abs(V).max() > FLOAT32_REACH * size:
        write_ply(path, V, F, colors=colours, dtype=np.float64)
    else:
        write_mesh(path, V, F, colours)


def surface_vertices(faces, count):
    """(the vertices some face uses, in order; the faces renumbered over them) of a mesh of
    ``count`` vertices."""
    used = np.unique(faces)
    number = np.full(count, -1, dtype=np.int64)
    number[used] = np.arange(len(used))
    return used, number[faces]


def _load(paths, progress):
    """The meshes read and checked: (meshes, the vertices some face uses, the faces renumbered over
    them)."""
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
    used, faces = surface_vertices(first.faces, len(first.vertices))  # stray points are not the surface's size
    sizes = [model_size(mesh.vertices[used]) for mesh in meshes]
    for path, size in zip(paths, sizes):
        if not (np.isfinite(size) and size > 0):
            raise ValueError(f"{path}: model size must be positive and finite, got {size} (all its vertices at "
                             "one point): nothing to blend")
    big, small = int(np.argmax(sizes)), int(np.argmin(sizes))
    if sizes[big] > MAX_SIZE_RATIO * sizes[small]:  # one decision of units for all: the same units, or a mistake
        raise ValueError(f"{paths[big]} is {sizes[big] / sizes[small]:.0f} times the size of {paths[small]}: "
                         "blend meshes in the same units (convert one, e.g. from millimetres to metres)")
    return meshes, used, faces


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
    try:   # before the meshes are read and blended
        writable_type(args.out)
    except ValueError as exc:
        raise ValueError(f"--out {exc}") from None
    bars = StageBars()
    try:
        (meshes, convention), result, elapsed, n = _blend(args, w, bars)
    finally:
        bars.close()
    N = len(meshes)
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

    Returns ((meshes, convention), result, seconds, vertices): the input meshes in metres, +Y up
    (their surface: the vertices some face uses) and what their files were in, the blends of that
    surface by mode computed on the way (metres, +Y up; ``result[args.mode]`` is the one written,
    converted back), the seconds from the meshes read to the blend written, and the vertex count
    written (the files' own)."""
    read, used, faces = _load(args.meshes, progress)

    def say(line):  # tqdm.write: the line goes above the progress bar instead of onto its line
        tqdm.write(f"morphspace blend: {line}", file=sys.stderr)

    if len(used) < len(read[0].vertices):
        say(f"{len(read[0].vertices) - len(used)} vertices that no face uses are left out of the blend (their "
            "units, size and solid) and written at the weights' mean of their places")
    meshes, convention = meshes_to_metres([Mesh(vertices=m.vertices[used], faces=faces, source=m.source,
                                                colors=None if m.colors is None else m.colors[used])
                                           for m in read], args.units, args.up)
    say_conventions([convention], ["the meshes"], say)
    # blended about the first mesh's centre (float64) in float32: a capture far from its origin
    # (survey coordinates) keeps its millimetres
    centre = meshes[0].vertices.mean(axis=0)
    sources = np.stack([m.vertices - centre for m in meshes])[None].astype(np.float32)  # (P=1, N, n, 3)
    N, n = sources.shape[1:3]
    linear = LinearBlender(sources, cyclic=True)
    started = time.perf_counter()
    result = {}
    if args.mode == "linear" and not args.compare:
        progress("solve", 0, 1)
        result["linear"] = linear.blend(w, 0.0)
        progress("solve", 1, 1)
    else:
        rest = meshes[0].vertices - centre
        if args.rest is not None:
            rest_mesh = read_mesh(args.rest)
            if rest_mesh.vertices.shape != read[0].vertices.shape or not np.array_equal(rest_mesh.faces,
                                                                                         read[0].faces):
                raise ValueError(f"{args.rest}: the rest mesh must have the same topology as the inputs")
            # as the inputs
            rest = to_metres_y_up(rest_mesh.vertices[used], convention.units, convention.up) - centre
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
    if all(m.colors is not None for m in read):
        colours = np.clip(np.einsum("k,kic->ic", w / w.sum(), np.stack([m.colors for m in read])), 0.0, 1.0)
    result = {mode: np.asarray(blend, dtype=np.float64) + centre for mode, blend in result.items()}
    # the files' own vertices back: the blended surface, and the stray points at their mean
    out = np.einsum("k,kic->ic", w / w.sum(), np.stack([m.vertices for m in read]))
    out[used] = from_metres_y_up(result[args.mode], convention.units, convention.up)
    _write(args.out, out, read[0].faces, colours, model_size(out[used]))
    progress("write", 1, 1)
    return (meshes, convention), result, time.perf_counter() - started, len(out)

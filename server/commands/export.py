"""Export a clip of a motion space, or a graph's performance: glTF, USD, OBJ/PLY frames, a VAT.

Formats: binary glTF, USD, an OBJ / PLY sequence or a vertex-animation texture (docs/exports.md).

The clip is played by the real-time player (the frames a stream at that rate shows): start at
--set parameters, request others --at later times (or from a --track JSON file), for --seconds
at --fps. Examples:

    morphspace export data/spaces/locomotion.mspace --out walk.glb --set speed=1.3 \\
        --at 3 speed=2.5 --at 6 turn_rate=30 --seconds 10 --fps 60
    morphspace export data/spaces/jumps.mspace --out jump.usd --set jump_height=0.45 --seconds 2
    morphspace export data/spaces/locomotion.mspace --out frames/ --format ply --track track.json

A motion graph (``.mgraph``) exports a recorded performance (server/commands/export_graph.py):

    morphspace export data/spaces/demo.mgraph --recording session.json --out perf.glb
    morphspace export data/spaces/demo.mgraph --out perf.usd --at 1 jump jump_height=0.5 --seconds 6
"""

from __future__ import annotations

import json
import re
import sys
import time
from pathlib import Path

from engine.export import Clip, check_clip, parse_track, play_clip, write_export
from engine.export.gltf import INTERPOLATIONS, PRECISIONS
from engine.export.sequence import MESH_SUFFIXES
from engine.motion_space import MotionSpace
from engine.player import SMOOTHING
from server.commands.play import _assignments, check_clock, scripted

SUFFIXES = {".glb": "glb", ".usd": "usd", ".usdc": "usd", ".usda": "usd"}


def add_arguments(parser):
    parser.add_argument("space", type=Path, help="a .mspace file with parameters, or a .mgraph motion graph")
    parser.add_argument("--out", type=Path, required=True,
                        help="file (.glb, .usd/.usdc/.usda, .zip) or directory (obj/ply sequence)")
    parser.add_argument("--format", choices=("glb", "usd", "obj", "ply", "vat"),
                        help="default: from --out's suffix (.glb, .usd*); obj/ply/vat need --format")
    parser.add_argument("--set", nargs="+", action="extend", default=[], metavar="NAME=VALUE",
                        help="parameters at t = 0 (a graph: the start node's)")
    parser.add_argument("--at", nargs="+", action="append", default=[], metavar="T NAME=VALUE",
                        help="at time T (s) request parameters (repeat for a script); a graph: "
                             "T NODE [NAME=VALUE ...] [budget=S], as morphspace play takes it")
    parser.add_argument("--recording", type=Path,
                        help="a graph: the recorded performance to export (morphspace play --record, or the "
                             "browser's Record button)")
    parser.add_argument("--start", help="a graph: the start node of a scripted performance (default: the first "
                                        "cyclic node)")
    parser.add_argument("--track", type=Path, help='JSON {"params": {...}, "track": [{"time": T, "params": {...}}]}')
    parser.add_argument("--seconds", type=float, help="clip length (default 10 s; a scripted graph "
                                                       "performance: 4 s after the last request)")
    parser.add_argument("--fps", type=float, default=60.0, help="frames per second (default 60)")
    parser.add_argument("--mode", choices=("linear", "hybrid", "nonlinear"), default="hybrid")
    parser.add_argument("--smoothing", type=float, help="a space: parameter time constant, s (default 0.25)")
    parser.add_argument("--precision", choices=PRECISIONS, default="int16",
                        help="glTF vertex storage (default int16, KHR_mesh_quantization; float32: exact)")
    parser.add_argument("--interpolation", choices=INTERPOLATIONS, default="LINEAR",
                        help="glTF weights sampling between frames (default LINEAR)")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def output_format(out, chosen):
    """The export format for ``--out`` and ``--format``; errors say what to give."""
    inferred = SUFFIXES.get(out.suffix.lower())
    if chosen is None:
        if inferred is None:
            raise ValueError(f"--out {out}: cannot tell the format from the name; give --format glb, usd, obj, ply "
                             "or vat")
        return inferred
    if chosen in ("glb", "usd") and inferred != chosen:
        wanted = ".glb" if chosen == "glb" else ".usd, .usdc or .usda"
        raise ValueError(f"--out {out}: a {chosen} export must be a file ending in {wanted}")
    if chosen in ("obj", "ply", "vat") and (inferred is not None or out.suffix.lower() in FRAME_SUFFIXES):
        # (frame_0000.obj would become a directory of that name, holding the frames)
        article = "an" if chosen == "obj" else "a"
        raise ValueError(f"--out {out}: {article} {chosen} export is a directory or a .zip file, not a file of its "
                         f"({out.suffix}); give the directory to write it into")
    return chosen


FRAME_SUFFIXES = (".obj", ".ply", ".png", ".json")  # names of the files a directory export holds


def clip_from_arguments(args, names):
    params, track = {}, []
    if args.track:
        try:
            document = json.loads(args.track.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"--track {args.track}: not JSON ({exc})") from None
        params, track = parse_track(document, str(args.track))
    params.update(_assignments(args.set, names))
    track.extend(scripted(args.at, names))
    return Clip(params=params, track=tuple(track), duration=10.0 if args.seconds is None else args.seconds,
                rate=args.fps, mode=args.mode, smoothing=SMOOTHING if args.smoothing is None else args.smoothing)


class _Bar:
    """One tqdm bar per stage on stderr (none with --quiet)."""

    def __init__(self, quiet):
        self.quiet, self.bar = quiet, None

    def stage(self, name, total):
        from tqdm import tqdm

        self.close()
        if not self.quiet:
            self.bar = tqdm(total=total, desc=name, unit="frame", file=sys.stderr, leave=True)
        return self.update

    def update(self, done, total):
        if self.bar is not None:
            self.bar.update(done - self.bar.n)

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


EXPORT_FILES = re.compile(r"frame_\d+\.(obj|ply)|clip\.json|vat\.json|mesh\.glb|positions\.png")  # what exports write


def clear_export(directory):
    """Remove from ``directory`` the files an earlier sequence or VAT export wrote there (its frames,
    ``clip.json``; ``vat.json``, ``mesh.glb``, ``positions.png``), so that ``--force`` replaces it; other
    files stay (a sequence export then refuses other mesh files)."""
    for path in sorted(directory.iterdir()):
        if path.is_file() and EXPORT_FILES.fullmatch(path.name):
            path.unlink()


def replace_export(out, force):
    """With ``force``, an existing directory ``out`` loses what an earlier export wrote there, just
    before the new one is written (every check passed). Other mesh files there are refused first,
    before anything is removed: the refusal used to come after the earlier export was gone."""
    if not (force and out.is_dir()):
        return
    other = sorted(p.name for p in out.iterdir() if p.is_file() and p.suffix.lower() in MESH_SUFFIXES
                   and not EXPORT_FILES.fullmatch(p.name))
    if other:
        raise ValueError(f"{out}: holds {len(other)} mesh files no export wrote (e.g. {other[0]}); nothing was "
                         f"removed; export into an empty directory")
    clear_export(out)


def run(args):
    fmt = output_format(args.out, args.format)
    check_clock(args.fps, args.seconds)  # named by their options (the clip's own check said "duration", "rate")
    if args.out.exists() and not args.force:
        raise ValueError(f"--out {args.out} exists; pass --force to replace it")
    if args.space.suffix == ".mgraph":
        from server.commands.export_graph import run_graph

        bar = _Bar(args.quiet)
        try:
            return run_graph(args, fmt, bar)
        finally:
            bar.close()
    if args.recording or args.start:
        raise ValueError("--recording and --start are for motion graphs (.mgraph)")
    space = MotionSpace.open(args.space)
    if space.parameter_map is None:
        raise ValueError(f"{args.space}: the space has no parameter map (build it from a spec with parameters)")
    clip = clip_from_arguments(args, list(space.parameter_map.names))
    check_clip(space, clip)
    bar = _Bar(args.quiet)
    started = time.perf_counter()
    try:
        frames = play_clip(space, clip, progress=bar.stage("play", clip.n_frames))
        played = time.perf_counter()
        replace_export(args.out, args.force)
        stats = write_export(args.out, frames, fmt, progress=bar.stage("write", clip.n_frames),
                             precision=args.precision, interpolation=args.interpolation)
    finally:
        bar.close()
    done = time.perf_counter()
    print(f"{space.name}: {len(frames)} frames ({clip.duration:g} s at {clip.rate:g} frames/s, {clip.mode}) -> "
          f"{args.out} ({fmt}, {stats['bytes'] / 1e6:.2f} MB); played in {played - started:.2f} s, written in "
          f"{done - played:.2f} s")
    if fmt == "glb":
        print(f"  {stats['targets']} morph targets ({stats['dense_targets']} dense, {stats['sparse_targets']} "
              f"sparse, {stats['empty_targets']} empty), {args.precision}, largest error "
              f"{1000 * stats['max_error_m']:.3f} mm")
    for note in frames.notes:
        print(f"  note: {note}")
    return 0

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

import contextlib
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
from server.units import count_text

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
    parser.add_argument("--fps", type=float, help="frames per second (default 60; a recording has its own)")
    parser.add_argument("--mode", choices=("linear", "hybrid", "nonlinear"),
                        help="blend mode (default hybrid; a recording has its own)")
    parser.add_argument("--smoothing", type=float, help="a space: parameter time constant, s (default 0.25)")
    parser.add_argument("--precision", choices=PRECISIONS,
                        help="glb only: vertex storage (default int16, KHR_mesh_quantization; float32: exact)")
    parser.add_argument("--interpolation", choices=INTERPOLATIONS,
                        help="glb only: weights sampling between frames (default LINEAR)")
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
        raise ValueError(f"--out {out}: {article} {chosen} export is a directory or a .zip file, not a {out.suffix} "
                         f"file; give the directory to write it into")
    return chosen


def check_export_options(args, fmt):
    """Fill in the defaults of ``--fps``, ``--mode``, ``--precision`` and ``--interpolation``, refusing
    each where it would be ignored: the glTF options for other formats, the clock and mode with a
    recording (which has its own), as ``--seconds`` is refused there."""
    for option, value in (("--precision", args.precision), ("--interpolation", args.interpolation)):
        if value is not None and fmt != "glb":
            raise ValueError(f"{option} is for glb exports; a {fmt} export has no such choice")
    if getattr(args, "recording", None):
        for option, value in (("--fps", args.fps), ("--mode", args.mode)):
            if value is not None:
                raise ValueError(f"{option}: --recording replays a recorded performance at its own frame rate and "
                                 f"blend mode; leave {option} out")
    args.precision = args.precision or "int16"
    args.interpolation = args.interpolation or "LINEAR"
    args.fps = 60.0 if args.fps is None else args.fps
    args.mode = args.mode or "hybrid"


def check_export_limits(fps, seconds):
    """``--fps`` and ``--seconds`` within what the REST export takes (``ExportSpec``'s ``rate`` and
    ``duration``): the CLI writes what the server would."""
    from server.jobs.models import ExportSpec

    for option, value, field, unit in (("--fps", fps, "rate", "frames per second"),
                                       ("--seconds", seconds, "duration", "seconds")):
        top = next(m.le for m in ExportSpec.model_fields[field].metadata if hasattr(m, "le"))
        if value is not None and value > top:
            raise ValueError(f"{option} {value:g}: at most {top:g} {unit} (as the REST export's {field!r} takes it)")


def check_export_path(out, fmt):
    """Refuse an ``--out`` that cannot be written, before anything is played: a file export
    (glb, usd, a .zip) that names a directory, or a path under a file."""
    if out.is_dir() and (fmt in ("glb", "usd") or out.suffix.lower() == ".zip"):
        raise ValueError(f"--out {out} is a directory; a {fmt} export{' to a .zip' if fmt not in ('glb', 'usd') else ''} "
                         f"is a file")
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"--out {out}: {parent} is a file, not a directory")
            break


def read_json_option(path, option):
    """The JSON document in the file ``option`` names, or a ValueError naming the option and the file."""
    try:
        text = Path(path).read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise ValueError(f"{option} {path}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"{option} {path}: is a directory, not a JSON file") from None
    except UnicodeDecodeError:
        raise ValueError(f"{option} {path}: not a JSON text file (it is not UTF-8 text)") from None
    except OSError as exc:
        raise ValueError(f"{option} {path}: cannot read it ({exc.strerror or exc})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{option} {path}: not JSON ({exc})") from None


@contextlib.contextmanager
def writing(out):
    """OS errors while the export is written, as one line naming ``--out`` (not the temporary file's name)."""
    try:
        yield
    except OSError as exc:
        if str(exc).startswith("cannot write "):  # the writers' own (engine.mesh_io.atomic, engine.export.usd)
            raise ValueError(str(exc)) from None
        raise ValueError(f"cannot write {out}: {exc.strerror or exc}") from None


FRAME_SUFFIXES = (".obj", ".ply", ".png", ".json")  # names of the files a directory export holds


def clip_from_arguments(args, names):
    params, track = {}, []
    if args.track:
        params, track = parse_track(read_json_option(args.track, "--track"), str(args.track))
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
        raise ValueError(f"{out}: holds {count_text(len(other), 'mesh file')} no export wrote (e.g. {other[0]}); nothing "
                         f"was removed; export into an empty directory")
    clear_export(out)


def run(args):
    fmt = output_format(args.out, args.format)
    check_export_options(args, fmt)
    check_clock(args.fps, args.seconds)  # named by their options (the clip's own check said "duration", "rate")
    check_export_limits(args.fps, args.seconds)
    if args.out.exists() and not args.force:
        raise ValueError(f"--out {args.out} exists; pass --force to replace it")
    check_export_path(args.out, fmt)
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
        with writing(args.out):
            replace_export(args.out, args.force)
            stats = write_export(args.out, frames, fmt, progress=bar.stage("write", clip.n_frames),
                                 precision=args.precision, interpolation=args.interpolation)
    finally:
        bar.close()
    done = time.perf_counter()
    print(f"{space.name}: {count_text(len(frames), 'frame')} ({clip.duration:g} s at {clip.rate:g} frames/s, {clip.mode}) -> "
          f"{args.out} ({fmt}, {stats['bytes'] / 1e6:.2f} MB); played in {played - started:.2f} s, written in "
          f"{done - played:.2f} s")
    if fmt == "glb":
        print(f"  {stats['targets']} morph targets ({stats['dense_targets']} dense, {stats['sparse_targets']} "
              f"sparse, {stats['empty_targets']} empty), {args.precision}, largest error "
              f"{1000 * stats['max_error_m']:.3f} mm")
    for note in frames.notes:
        print(f"  note: {note}")
    return 0

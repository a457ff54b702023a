"""Build a motion space from a spec (TOML) or from --source sequences.

The spec names the sources, the high-level parameters and the blend settings
(docs/file-formats.md, "Motion space specs"); the build runs root motion, time-warp,
tetrahedralisation, decomposition, hybrid precompute and the parameter map, with progress bars.
Examples:

    morphspace build specs/demo/locomotion.toml --out data/spaces/locomotion.mspace
    morphspace build --source data/captures/demo/sequences/walk_slow \\
                     --source data/captures/demo/sequences/jog --out walk_jog.mspace

A --source is a capture-dataset sequence directory (its meta.json gives the frame rate and
whether it is cyclic) or any directory or zip of per-frame meshes (non-cyclic unless --cyclic).
Cycle lengths, key poses and events are found on the meshes. Sources in centimetres or
millimetres, or with +Z up, are converted to metres with +Y up first (--units, --up; detected by
default, and said on stderr); the space is in metres, +Y up.
"""

from __future__ import annotations

import json
import sys
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np

from engine.blend.hybrid_build import MAX_REFERENCES
from engine.mesh_io import read_mesh, read_sequence, to_metres_y_up
from engine.motion_space import SourceClip, build_motion_space
from engine.parameters import MEASURES, Layout
from server.progress import StageBars
from server.commands.checks import MAX_FPS, check_number, check_output_file, read_meta
from server.units import add_units_arguments, decide_convention, declared_convention, say_conventions, source_metadata

LAYOUT_KEYS = {"chain": ("chain",), "grid": ("corners",), "fan": ("chain", "left", "right")}
LAYOUT_FIELDS = ("chain", "corners", "left", "right")  # every layout's keys naming sources
SPEC_KEYS = ("name", "captures", "epsilon_mm", "phases", "rest", "sources", "parameters")
PARAMETER_KEYS = ("layout", "chain", "corners", "left", "right", "measures", "resolution")
SOURCE_KEYS = ("name", "path")
EPSILON_MM = (0.0, 100.0)   # the hybrid's error bound: above the first, at most the second (as the REST job)
PHASES = (2, 512)           # phase samples (as the REST job)
RESOLUTION = (2, 41)        # samples per layout axis of the parameter map (as the REST job)
MAX_MEASURES = 3


def add_arguments(parser):
    parser.add_argument("spec", nargs="?", type=Path, help="a space spec (.toml)")
    parser.add_argument("--source", action="append", type=Path, metavar="DIR",
                        help="a source sequence, instead of a spec (repeat; at least 2)")
    parser.add_argument("--out", type=Path, help="output .mspace file (default: the spec's name next to it)")
    parser.add_argument("--name", help="space name (default: from the spec, or the output file's stem)")
    parser.add_argument("--epsilon-mm", type=float, help=f"hybrid error bound in mm, above {EPSILON_MM[0]:g} and at "
                        f"most {EPSILON_MM[1]:g} (default: spec, or 5)")
    parser.add_argument("--phases", type=int, help=f"phase samples, {PHASES[0]} to {PHASES[1]} (default: spec, or the "
                        "longest source)")
    parser.add_argument("--rest", type=Path, help="rest-pose mesh (default: the capture dataset's "
                        "template/body.obj, else the first source's first frame)")
    parser.add_argument("--fps", type=float, default=30.0, help=f"frame rate of sources without meta.json (or whose "
                        f"meta.json has no fps), above 0 and at most {MAX_FPS:g}")
    parser.add_argument("--cyclic", action="store_true", help="sources without meta.json (or whose meta.json does "
                        "not say) are cyclic")
    add_units_arguments(parser)
    parser.add_argument("--force", action="store_true", help="replace an existing output file")


def load_source(directory, *, fps, cyclic):
    """SourceClip from a capture-dataset sequence directory or a directory/zip of frames.

    A sequence directory's meta.json gives the name, frame rate and whether the source is cyclic;
    what it does not give is the directory's name, ``fps`` and ``cyclic``."""
    directory = Path(directory)
    if (directory / "meta.json").is_file():
        meta = read_meta(directory)
        sequence = read_sequence(directory / "consistent")
        return SourceClip(name=meta.get("name", directory.name), vertices=sequence.vertices,
                          fps=float(meta.get("fps", fps)), cyclic=meta.get("cyclic", cyclic)), sequence.faces
    if (directory / "manifest.json").is_file() and (directory / "sequences").is_dir():
        have = sorted(p.name for p in (directory / "sequences").iterdir() if p.is_dir())
        raise ValueError(f"{directory} is a capture dataset, not a sequence: use its sequences/<name> (it has "
                         f"{', '.join(have[:8]) + (', ...' if len(have) > 8 else '') or 'none'})")
    sequence = read_sequence(directory)
    return SourceClip(name=directory.stem, vertices=sequence.vertices, fps=fps, cyclic=cyclic), sequence.faces


def read_toml(path, what, missing=None):
    """A TOML file as a dict; a missing or malformed file is a ValueError naming it and ``what`` it is."""
    if Path(path).is_dir():
        raise ValueError(f"{path} is a directory, not a {what} file")
    try:
        return tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: {missing or 'no such ' + what}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a valid TOML {what}: {exc}") from None


def check_keys(path, table, known, where=""):
    """Refuse keys of a spec table not in ``known``, naming the spec, the table (``where``) and them."""
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ValueError(f"{path}: {where}unknown key(s) {', '.join(unknown)}; known: {', '.join(known)}")


def check_file_name(path, value, key):
    """``value`` if it can name an output file beside others (a non-empty string without '/' or '\\',
    not starting with '.'), else a ValueError naming the spec and ``key``."""
    if not isinstance(value, str) or not value or value.startswith(".") or "/" in value or "\\" in value:
        raise ValueError(f"{path}: {key} must be a non-empty string without '/' or '\\', not starting with '.' "
                         f"(it names the output file), got {value!r}")
    return value


def foreign_layout_key(kind, given):
    """``"KEY is not part of a KIND layout (it takes ...)"`` for the first key of another layout
    among ``given`` (keys of a parameters table), else None."""
    key = next((k for k in LAYOUT_FIELDS if k in given and k not in LAYOUT_KEYS[kind]), None)
    return None if key is None else f"{key} is not part of a {kind} layout (it takes {', '.join(LAYOUT_KEYS[kind])})"


def layout_sources_problem(kind, placed, sources):
    """What is wrong with the source names a ``kind`` layout places (``placed``, in its keys'
    order) among a spec's ``sources``: a name that is not a source, a source placed twice, a
    source left out; None when nothing is (``read_spec`` and the REST build job ask alike)."""
    unknown = next((name for name in placed if name not in sources), None)
    if unknown is not None:
        return f"parameters refer to {unknown!r}, which is not among the sources"
    twice = next((name for name in placed if placed.count(name) > 1), None)
    if twice is not None:
        return f"parameters: the {kind} layout names {twice!r} twice; its sources must differ"
    left_out = [repr(name) for name in sources if name not in placed]
    if left_out:
        return (f"parameters: the {kind} layout leaves out {', '.join(left_out)}: every source needs its place in "
                "the layout (add it there, or take it out of sources)")
    return None


def read_spec(path):
    """Parse and check a space spec; returns a dict with resolved source directories.

    Every key's type and range is checked and unknown keys are refused (docs/file-formats.md,
    "Motion space specs"); errors name the spec, the key and the problem."""
    path = Path(path)
    spec = read_toml(path, "spec", missing="no such spec file")
    check_keys(path, spec, SPEC_KEYS)
    base = path.parent
    name = check_file_name(path, spec["name"], "name") if "name" in spec else path.stem
    for key in ("captures", "rest"):
        if key in spec and (not isinstance(spec[key], str) or not spec[key]):
            raise ValueError(f"{path}: {key} must be a path (a non-empty string), got {spec[key]!r}")
    captures = base / spec["captures"] if "captures" in spec else None
    sources = spec.get("sources")
    if not isinstance(sources, list) or len(sources) < 2:
        raise ValueError(f"{path}: 'sources' must list at least 2 sequences")
    names, directories = [], []
    for entry in sources:
        if isinstance(entry, str):
            entry = {"name": entry}
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str) or not entry["name"] or (
                "path" in entry and (not isinstance(entry["path"], str) or not entry["path"])):
            raise ValueError(f"{path}: each source is a sequence name or a table with 'name' (and 'path'), "
                             f"both strings; got {entry!r}")
        check_keys(path, entry, SOURCE_KEYS, f"source {entry['name']!r}: ")
        if entry["name"] in names:
            raise ValueError(f"{path}: source {entry['name']!r} is listed twice; sources must be different sequences")
        if "path" in entry:
            directory = base / entry["path"]
        elif captures is not None:
            directory = captures / "sequences" / entry["name"]
        else:
            raise ValueError(f"{path}: source {entry['name']!r} has no 'path' and the spec no 'captures'")
        if not directory.exists():
            raise ValueError(f"{path}: source {entry['name']!r}: {directory} does not exist")
        names.append(entry["name"])
        directories.append(directory)
    if spec.get("epsilon_mm") is not None:
        check_number(spec["epsilon_mm"], f"{path}: epsilon_mm", *EPSILON_MM, above=True, unit="(mm)")
    if spec.get("phases") is not None:
        check_number(spec["phases"], f"{path}: phases", *PHASES, integer=True)
    parameters = spec.get("parameters")
    layout = None
    if parameters is not None:
        if not isinstance(parameters, dict):
            raise ValueError(f"{path}: parameters must be a table ([parameters]), got {parameters!r}")
        check_keys(path, parameters, PARAMETER_KEYS, "parameters: ")
        kind = parameters.get("layout")
        if kind not in LAYOUT_KEYS:
            raise ValueError(f"{path}: parameters.layout must be one of {', '.join(LAYOUT_KEYS)}, got {kind!r}")
        foreign = foreign_layout_key(kind, parameters)
        if foreign is not None:
            raise ValueError(f"{path}: parameters.{foreign}")
        placed = []
        for key in LAYOUT_KEYS[kind]:
            if key not in parameters:
                raise ValueError(f"{path}: a {kind} layout needs parameters.{key}")
            value = parameters[key]
            if key in ("chain", "corners"):
                if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                    raise ValueError(f"{path}: parameters.{key} must be a list of source names, got {value!r}")
            elif not isinstance(value, str):
                raise ValueError(f"{path}: parameters.{key} must be a source name, got {value!r}")
            placed += value if isinstance(value, list) else [value]
        problem = layout_sources_problem(kind, placed, names)
        if problem is not None:
            raise ValueError(f"{path}: {problem}")
        fields = {key: tuple(names.index(v) for v in parameters[key]) if key in ("chain", "corners")
                  else names.index(parameters[key]) for key in LAYOUT_KEYS[kind]}
        try:
            layout = Layout(kind=kind, n_sources=len(names), **fields)
        except ValueError as exc:
            raise ValueError(f"{path}: parameters: {exc}") from None
        measures = parameters.get("measures")
        if (not isinstance(measures, list) or not 1 <= len(measures) <= MAX_MEASURES
                or any(not isinstance(m, str) or m not in MEASURES for m in measures)
                or len(set(measures)) != len(measures)):
            raise ValueError(f"{path}: parameters.measures must list 1 to {MAX_MEASURES} different ones of "
                             f"{', '.join(MEASURES)}, got {measures!r}")
        resolution = parameters.get("resolution")
        if resolution is not None:
            check_number(resolution, f"{path}: parameters.resolution", *RESOLUTION, integer=True)
        parameters = {"layout": layout, "names": list(measures), "resolution": resolution}
    rest = spec.get("rest")
    rest = (captures / rest if captures is not None else base / rest) if rest else None
    if rest is not None and not rest.is_file():
        raise ValueError(f"{path}: rest: {rest} is not a file")
    return {"name": name, "directories": directories, "names": names,
            "epsilon_mm": spec.get("epsilon_mm"), "phases": spec.get("phases"), "rest": rest,
            "captures": captures, "parameters": parameters}


def load_sources(directories, *, fps, cyclic, progress=None, log=None):
    """SourceClips of ``directories`` and their shared faces; an error names a source whose
    mesh structure differs from the first one's."""
    clips, faces = [], None
    for k, directory in enumerate(directories):
        if progress:
            progress("read", k, len(directories))
        clip, F = load_source(directory, fps=fps, cyclic=cyclic)
        if faces is not None and (F.shape != faces.shape or not np.array_equal(F, faces)):
            raise ValueError(f"{directory}: its faces differ from {directories[0]}'s; "
                             "all sources need the same mesh structure")
        if len(clip.vertices) < 2:  # (root motion and phases need at least two)
            raise ValueError(f"{directory}: {len(clip.vertices)} frame; a source needs at least 2")
        faces = F
        clips.append(clip)
        if log:
            log(f"read {clip.name}: {len(clip.vertices)} frames at {clip.fps:g} fps{' (cyclic)' if clip.cyclic else ''}")
    if progress:
        progress("read", len(directories), len(directories))
    return clips, faces


def choose_rest(clips, faces, rest_path, template):
    """(rest vertices, note, heading turn): the given rest mesh (it must match the sources), else
    the dataset's ``template`` when it matches, else the first source's first frame. The turn
    (radians, or None) is the capture's own when the rest is an aligned capture's template
    (``capture_heading_turn``)."""
    rest = clips[0].vertices[0]
    for path, strict in ((rest_path, True), (template, False)):
        if path is None or (not strict and not Path(path).is_file()):
            continue
        mesh = read_mesh(path)
        if mesh.vertices.shape == clips[0].vertices.shape[1:] and np.array_equal(mesh.faces, faces):
            return mesh.vertices, f"resting on {path}", capture_heading_turn(path)
        if strict:
            raise ValueError(f"{path}: the rest mesh must have the sources' vertices and faces")
        return rest, f"{path} does not match the sources' mesh; resting on the first frame", None
    return rest, "resting on the first frame", None


def capture_heading_turn(rest_path):
    """The heading turn (radians) an aligned capture recorded for its rest, when ``rest_path`` is
    that capture's ``template/body.obj`` (its manifest's ``body.heading_turn_deg``, written by
    ``align``); else None, and the space takes its own sources' travel."""
    path = Path(rest_path)
    if path.name != "body.obj" or path.parent.name != "template":
        return None
    body = _json_record(path.parent.parent / "manifest.json", "body")
    turn = body.get("heading_turn_deg") if isinstance(body, dict) else None
    return float(np.radians(turn)) if isinstance(turn, (int, float)) and np.isfinite(turn) else None


def _json_record(path, key=None):
    try:
        record = json.loads(Path(path).read_text()) if Path(path).is_file() else None
    except (OSError, ValueError):
        return None
    return record.get(key) if key and isinstance(record, dict) else record


def sources_to_metres(clips, rest, directories, units="auto", up="auto"):
    """Sources and rest shape in metres with +Y up, each decided on its own.

    A source is decided on its frames, then (when the geometry cannot tell) its meta.json and
    its dataset manifest's ``body`` ("units", "up"; an aligned dataset says m, +Y); the rest
    shape on its own vertices and the manifest's ``body`` (a dataset's template is in the
    body's units even when some sequences are not).

    Returns
    -------
    clips : list of SourceClip   rest : (n, 3) float array
    conventions : list of engine.mesh_io.Convention   one per source, then the rest shape's
    """
    converted, conventions = [], []
    for clip, directory in zip(clips, map(Path, directories)):
        body = _json_record(directory.parent.parent / "manifest.json", "body")
        declared = declared_convention([_json_record(directory / "meta.json"), body])
        convention = decide_convention(clip.vertices, units, up, declared)
        if (convention.units, convention.up) != ("m", "y"):
            clip = replace(clip, vertices=to_metres_y_up(clip.vertices, convention.units, convention.up))
        converted.append(clip)
        conventions.append(convention)
    declared = declared_convention([_json_record(Path(directories[0]).parent.parent / "manifest.json", "body")])
    convention = decide_convention([rest], units, up, declared)
    conventions.append(convention)
    return converted, to_metres_y_up(rest, convention.units, convention.up), conventions


def run(args):
    if args.spec is None and not args.source:
        raise ValueError("give a spec file or at least two --source sequences")
    if args.spec is not None and args.source:
        raise ValueError("give either a spec or --source sequences, not both")
    check_number(args.fps, "--fps", 0.0, MAX_FPS, above=True, unit="frames/s")
    if args.epsilon_mm is not None:
        check_number(args.epsilon_mm, "--epsilon-mm", *EPSILON_MM, above=True, unit="(mm)")
    if args.phases is not None:
        check_number(args.phases, "--phases", *PHASES, integer=True)
    if args.spec is not None:
        spec = read_spec(args.spec)
        directories, name = spec["directories"], args.name or spec["name"]
        out = args.out or args.spec.with_name(f"{spec['name']}.mspace")
    else:
        if len(args.source) < 2:
            raise ValueError("a motion space needs at least 2 --source sequences")
        seen = {}
        for source in args.source:   # the same take twice is no blend (a spec refuses it too)
            key = source.resolve()
            if key in seen:
                raise ValueError(f"--source {source}: given twice (also as {seen[key]}); sources must be "
                                 "different sequences")
            seen[key] = source
        if args.out is None:
            raise ValueError("--out is required with --source")
        spec = {"epsilon_mm": None, "phases": None, "rest": None, "parameters": None, "captures": None}
        directories, out = args.source, args.out
        name = args.name or out.stem
    epsilon_mm = next((e for e in (args.epsilon_mm, spec["epsilon_mm"]) if e is not None), 5.0)
    n_phases = next((p for p in (args.phases, spec["phases"]) if p is not None), None)
    rest_path = args.rest or spec["rest"]
    if args.rest is not None and not args.rest.is_file():
        raise ValueError(f"--rest {args.rest}: not a file")
    check_output_file(out, "--out" if args.out else None, inputs=[args.spec, *directories, rest_path])
    if out.exists() and not args.force:
        raise FileExistsError(f"{out} already exists; pass --force to replace it")

    clips, faces = load_sources(directories, fps=args.fps, cyclic=args.cyclic)
    rest, rest_note, turn = choose_rest(clips, faces, rest_path,
                                        Path(directories[0]).parent.parent / "template" / "body.obj")
    clips, rest, conventions = sources_to_metres(clips, rest, directories, args.units, args.up)
    say = lambda line: print(f"morphspace build: {line}", file=sys.stderr)  # noqa: E731
    say(f"rest shape: {rest_note}")
    if turn is not None:
        say(f"heading 0: the aligned capture's travel, {np.degrees(turn):+.1f} degrees from the rest's facing")
    say_conventions(conventions, [clip.name for clip in clips] + ["the rest shape"], say, what="source")
    bars = StageBars()
    started = time.perf_counter()
    report = build_motion_space(out, clips, faces, name=name, n_phases=n_phases,
                                epsilon=epsilon_mm / 1000.0, rest=rest, parameters=spec["parameters"],
                                metadata=source_metadata([clip.name for clip in clips], conventions[:-1],
                                                         conventions[-1]),
                                progress=bars, heading_turn=turn)
    bars.close()
    hybrid = report["hybrid"]
    print(f"wrote {out}: {report['n_sources']} sources x {report['n_phases']} phases, "
          f"{report['n_vertices']} vertices, {report['n_tets']} tets, in {time.perf_counter() - started:.1f} s")
    print(f"  hybrid: {hybrid['references']} references, {hybrid['leaves']} cells, max test error "
          f"{hybrid['max_test_error'] * 1000:.2f} mm (epsilon {epsilon_mm:g} mm), corrections "
          f"{hybrid['correction_bytes'] / 1e6:.2f} MB = {100 * hybrid['correction_bytes'] / hybrid['source_bytes']:.1f}% "
          f"of the sources")
    if hybrid.get("check_points"):
        print(f"  checked at {hybrid['check_points']} weights between the test points: max "
              f"{hybrid['max_check_error'] * 1000:.2f} mm ({hybrid['check_added']} over epsilon became test points)")
    if hybrid["max_test_error"] * 1000 > epsilon_mm or (hybrid.get("check_points")
                                                        and hybrid["max_check_error"] * 1000 > epsilon_mm):
        print(f"  the hybrid's bound is not met everywhere (its bisection stopped at its depth limit or at "
              f"{MAX_REFERENCES} references, or the check between the test points ran out of rounds): error up to "
              f"{max(hybrid['max_test_error'], hybrid.get('max_check_error') or 0.0) * 1000:.2f} mm; "
              "sources that blend badly need a parameter layout (without one) or fewer sources")
    if report.get("parameters"):
        p = report["parameters"]
        domain = ", ".join(f"{n} {lo:.3g}..{hi:.3g} {u}" for n, (lo, hi), u in zip(p["names"], p["domain"], p["units"]))
        print(f"  parameters ({p['layout']['kind']}): {domain}")
    return 0

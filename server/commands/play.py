"""Play a motion space or a motion graph headless under scripted requests.

Runs the real-time player (engine.player) on a fixed clock and reports what it did: realised vs
requested parameters over time, the path travelled, and optionally a trail picture (every n-th
frame along the path, like the paper's figs. 7-8) and the frames as OBJ files. Examples:

    morphspace play data/spaces/locomotion.mspace --set speed=1.3 turn_rate=0 \\
        --at 3 speed=2.6 --at 6 turn_rate=40 --seconds 10 --trail path.png
    morphspace play data/spaces/jumps.mspace --set jump_height=0.45 jump_distance=0.8 --json
    morphspace play data/spaces/demo.mgraph --set speed=1.3 --at 2 jump jump_height=0.45 \\
        --at 6 walk speed=1.5 --at 9 reach reach_height=1.8 --record session.json

With a motion graph (.mgraph) each ``--at`` names a node first (server/commands/play_graph.py).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from engine.export.clip import MAX_FRAMES
from engine.mesh_io import write_obj
from engine.motion_space import MotionSpace
from engine.player import SMOOTHING, Player
from server.commands.checks import check_output_path


def add_arguments(parser):
    parser.add_argument("space", type=Path, help="a .mspace file with parameters, or a .mgraph motion graph")
    parser.add_argument("--set", nargs="+", action="extend", default=[], metavar="NAME=VALUE", help="initial parameters")
    parser.add_argument("--at", nargs="+", action="append", default=[], metavar="T [NODE] NAME=VALUE",
                        help="at time T (s) request parameters (repeat for a script); with a graph, a node "
                             "first and optionally budget=S (the latency budget, s)")
    parser.add_argument("--start", help="graphs: the node to start in (default: the first cyclic node)")
    parser.add_argument("--record", type=Path, help="graphs: write the session's requests as a JSON recording")
    parser.add_argument("--replay", type=Path, help="graphs: replay a JSON recording (its own start, clock, mode "
                        "and requests) and check the frames are identical (exit status 1 if not)")
    parser.add_argument("--seconds", type=float, help="how long to play (default: a space 10 s, or its one-shot "
                        "clip once; a graph 4 s after the last --at)")
    parser.add_argument("--fps", type=float, default=60.0, help="player clock rate (default 60)")
    parser.add_argument("--mode", choices=("linear", "hybrid", "nonlinear"), default="hybrid")
    parser.add_argument("--smoothing", type=float, help="spaces: parameter time constant, s (default 0.25)")
    parser.add_argument("--loop", action="store_true", help="spaces: loop one-shot clips")
    parser.add_argument("--trail", type=Path, help="write a PNG of every n-th frame along the path")
    parser.add_argument("--trail-every", type=float, default=0.4, help="seconds between trail frames")
    parser.add_argument("--frames", type=Path, help="write every played frame as OBJ into this directory")
    parser.add_argument("--force", action="store_true", help="replace the frames of an earlier play in --frames")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")


def _assignments(items, names):
    out = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"expected NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        if name not in names:
            raise ValueError(f"unknown parameter {name!r}; this space has {', '.join(names)}")
        if name in out:
            raise ValueError(f"{name} is given twice ({name}={out[name]:g}, {item}); give each parameter once")
        out[name] = finite_number(name, value)
    return out


def finite_number(name, value):
    """``value`` (a string) as a float; a ValueError naming ``name`` unless it is a finite number."""
    try:
        number = float(value)
    except ValueError:
        raise ValueError(f"{name}: {value!r} is not a number") from None
    if not math.isfinite(number):
        raise ValueError(f"{name}: {value!r} is not a finite number")
    return number


def at_time(entry):
    """The time that starts an ``--at TIME ...`` entry: a finite number of seconds >= 0."""
    try:
        when = float(entry[0])
    except ValueError:
        raise ValueError(f"--at needs a time first, got {entry[0]!r}") from None
    if not (math.isfinite(when) and when >= 0):
        raise ValueError(f"--at {entry[0]}: the time must be a finite number of seconds >= 0")
    return when


def check_clock(fps, seconds):
    """``--fps`` and ``--seconds`` (None: the default) finite and positive, named by their options."""
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"--fps must be a finite positive number of frames per second, got {fps:g}")
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"--seconds must be a finite positive number of seconds, got {seconds:g}")


def check_arguments(args, graph=False):
    """Refuse bad numbers and output paths before anything is played or written (a ValueError naming the
    option): --fps and --seconds finite and positive, at most MAX_FRAMES frames, --smoothing and --trail-every
    for a space, --trail a picture file, --frames a directory, --record a file, --replay an existing file."""
    check_clock(args.fps, args.seconds)
    if args.seconds is not None:
        frame_steps(args.seconds, args.fps, f"--seconds {args.seconds:g}")
    if graph:
        if args.trail:
            raise ValueError("--trail is for motion spaces (.mspace); a graph's play writes its frames with --frames")
        for option, given in (("--smoothing", args.smoothing is not None), ("--loop", args.loop)):
            if given:   # a graph's nodes play as the graph player has them: said, not ignored
                raise ValueError(f"{option} is for motion spaces (.mspace): a graph's nodes smooth their "
                                 "parameters and play their one-shots as the graph player does")
    else:
        if args.smoothing is None:
            args.smoothing = SMOOTHING
        if not (math.isfinite(args.smoothing) and args.smoothing >= 0):
            raise ValueError(f"--smoothing must be a non-negative number of seconds, got {args.smoothing:g}")
        if not (math.isfinite(args.trail_every) and args.trail_every > 0):
            raise ValueError(f"--trail-every must be a positive number of seconds, got {args.trail_every:g}")
    if args.trail:
        from PIL import Image

        check_output_path(args.trail, "--trail")
        if args.trail.suffix.lower() not in Image.registered_extensions():
            raise ValueError(f"--trail {args.trail}: not a picture file name; give one ending in .png")
    if args.frames:
        check_output_path(args.frames, "--frames", directory=True)
        if args.frames.is_dir() and any(args.frames.glob("frame_*.obj")) and not args.force:
            # a shorter play would leave the earlier one's last frames behind, one sequence to the eye
            raise ValueError(f"--frames {args.frames}: holds the frames of an earlier play; pass --force to "
                             "replace them")
    if getattr(args, "record", None):
        check_output_path(args.record, "--record")
    if getattr(args, "replay", None):
        if args.replay.is_dir():
            raise ValueError(f"--replay {args.replay}: is a directory, not a recording")
        if not args.replay.is_file():
            raise ValueError(f"--replay {args.replay}: no such file")


def open_frames(directory):
    """Make ``--frames`` ready for a play: created, and an earlier play's ``frame_*.obj`` removed
    (``check_arguments`` refused it without ``--force``); other files are left alone."""
    directory.mkdir(parents=True, exist_ok=True)
    for old in directory.glob("frame_*.obj"):
        old.unlink()


def note_time(seconds):
    """A time of a note: 0.80 s, 1e+300 s (a request past the end may be anything)."""
    return f"t={seconds:.2f} s" if seconds < 1e9 else f"t={seconds:.6g} s"


def frame_steps(seconds, fps, what):
    """The steps after the first frame of ``seconds`` at ``fps``; a ValueError saying ``what`` asked for more than
    MAX_FRAMES frames (as ``morphspace export`` refuses them)."""
    steps = seconds * fps
    if not steps + 1 < MAX_FRAMES + 0.5:
        frames = (f"{math.floor(steps + 0.5) + 1}" if steps < 1e15 else f"about {steps:.3g}" if math.isfinite(steps)
                  else f"more than {MAX_FRAMES}")
        raise ValueError(f"{what} at --fps {fps:g} is {frames} frames; at most {MAX_FRAMES} per play")
    return int(round(steps))


def scripted(entries, names):
    """``--at TIME NAME=VALUE ...`` entries as [(time, {name: value})]."""
    for entry in entries:  # (a bare `--at 1` was accepted and did nothing; a docs-only user)
        if len(entry) == 1:
            raise ValueError(f"--at {entry[0]}: give NAME=VALUE after the time")
    return [(at_time(entry), _assignments(entry[1:], names)) for entry in entries]


def run(args):
    if args.space.suffix == ".mgraph":
        from server.commands.play_graph import run_graph

        return run_graph(args)
    if args.start or args.record or args.replay:
        raise ValueError("--start, --record and --replay are for motion graphs (.mgraph)")
    check_arguments(args)
    space = MotionSpace.open(args.space)
    if space.parameter_map is None:
        raise ValueError(f"{args.space}: the space has no parameter map (build it from a spec with parameters)")
    player = Player(space, mode=args.mode, smoothing=args.smoothing, loop=args.loop or None)
    names = player.names
    notes = []
    start = _assignments(args.set, names) if args.set else {}
    if start:
        solution = player.set_params(start, immediate=True)
        if solution.clamped:
            notes.append(f"t=0.00 s: {solution.message}")
    script = sorted(scripted(args.at, names), key=lambda item: item[0])
    duration = args.seconds or (10.0 if space.cyclic or args.loop else
                                player.track.duration(player._solution.weights) + 0.5)
    dt = 1.0 / args.fps
    steps = frame_steps(duration, args.fps, f"--seconds {duration:g}" if args.seconds else
                        f"{duration:g} s (the default --seconds)")
    log, trail = [], []
    every = max(1, int(round(min(args.trail_every * args.fps, steps + 1))))
    if args.frames:
        open_frames(args.frames)  # (checked by check_arguments)
    frame = player.frame()
    given, given_at = set(start), []  # the parameters asked for so far, per logged frame (the text says "default" before)
    for k in range(steps + 1):
        while script and script[0][0] <= k * dt + 1e-9:
            given.update(script[0][1])
            solution = player.set_params(script.pop(0)[1])
            if solution.clamped:
                notes.append(f"t={k * dt:.2f} s: {solution.message}")
        frame = player.step(dt) if k else frame
        log.append({"time": round(frame.time, 4), "phase": round(frame.phase, 4),
                    "asked": player.asked.round(4).tolist(), "requested": frame.requested.round(4).tolist(),
                    "realised": frame.realised.round(4).tolist(),
                    "root": frame.root_position.round(4).tolist(), "heading_deg": round(np.degrees(frame.heading), 3)})
        given_at.append(frozenset(given))
        if args.trail and k % every == 0:
            trail.append(frame.vertices.copy())
        if args.frames:
            write_obj(args.frames / f"frame_{k:05d}.obj", frame.vertices, space.faces, precision=6)
        if frame.finished and not args.loop:
            break
    end = log[-1]["time"]
    why = ("the one-shot clip ended (--loop plays it again)" if frame.finished and not args.loop
           else "--seconds ended the play")
    for at, params in script:  # requests the play never reached: said, not dropped silently
        asked = ", ".join(f"{name}={value:g}" for name, value in params.items())
        notes.append(f"{note_time(at)}: {asked} not applied: {why} at {end:.2f} s")
    root = np.array([entry["root"] for entry in log])
    travelled = float(np.sum(np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1)))
    report = {"space": space.name, "parameters": names, "mode": args.mode, "seconds": log[-1]["time"],
              "frames": len(log), "path_length_m": travelled, "end": log[-1], "notes": notes,
              "timeline": log[:: max(1, len(log) // 50)]}
    if args.trail:
        from PIL import Image

        from engine.render import render_meshes

        colours = [np.array([0.2 + 0.6 * t, 0.45, 0.9 - 0.6 * t]) for t in np.linspace(0, 1, len(trail))]
        image = render_meshes([(V, space.faces, c) for V, c in zip(trail, colours)], azimuth=35, elevation=40,
                              width=1400, height=900, title=f"{space.name}: every {args.trail_every:g} s")
        args.trail.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(args.trail)
        report["trail"] = str(args.trail)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{space.name}: played {report['seconds']:.2f} s ({report['frames']} frames, {args.mode}), "
          f"travelled {travelled:.2f} m")
    rows = list(range(0, len(log), max(1, len(log) // 10)))
    for row in rows + ([len(log) - 1] if rows[-1] != len(log) - 1 else []):
        entry = log[row]
        values = ", ".join(f"{n} {r:.3f} ({'asked' if n in given_at[row] else 'default'} {q:g})"
                           for n, q, r in zip(names, entry["asked"], entry["realised"]))
        print(f"  t {entry['time']:6.2f} s  phase {entry['phase']:.2f}  {values}  root {entry['root'][0]:+.2f}, "
              f"{entry['root'][2]:+.2f} m  heading {entry['heading_deg']:+.1f} deg")
    for note in notes:
        print(f"  note: {note}")
    if args.trail:
        print(f"  trail: {args.trail}")
    return 0

"""``morphspace play GRAPH.mgraph``: a scripted performance on a motion graph.

The script is ``--at T NODE [NAME=VALUE ...] [budget=S]`` requests (``--at 3 jump
jump_height=0.5``): the graph player plans each transition (when to leave, where to enter, how
long to blend) and plays on, one-shots returning to a cyclic node by themselves. It reports the
transitions and the path, can write every frame as OBJ (``--frames``), record the session's
requests (``--record``) and replay a recording to the same frames, byte for byte (``--replay``).
"""

from __future__ import annotations

import json
import math

import numpy as np

from engine.export.clip import MAX_FRAMES
from engine.graph import GraphError, MotionGraph
from engine.graph.recording import perform, read_recording, recording
from engine.mesh_io import write_obj
from server.commands.play import at_time, check_arguments, finite_number, frame_steps, note_time, open_frames


def node_assignments(items, node):
    """({name: value}, budget or None) of NAME=VALUE items for ``node`` (``budget=S`` is the latency budget)."""
    out, budget = {}, None
    for item in items:
        if "=" not in item:
            raise ValueError(f"expected NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        number = finite_number(name, value)
        if name in out or (name == "budget" and budget is not None):
            raise ValueError(f"{name} is given twice ({item} and before it); give each once")
        if name == "budget":
            budget = number
        elif name not in node.parameters:
            has = f"it has {', '.join(node.parameters)}" if node.parameters else "it has no parameters"
            raise ValueError(f"node {node.name!r} has no parameter {name!r}; {has}")
        else:
            out[name] = number
    return out, budget


def run_graph(args):
    check_arguments(args, graph=True)
    try:
        graph = MotionGraph.open(args.space)
    except GraphError as exc:
        raise ValueError(str(exc)) from None
    with graph:
        if args.replay:
            document = _read_replay(args.replay, graph)
            start, params, fps, steps = document["start"], document["params"], document["fps"], document["steps"]
            mode, requests = document["mode"], document["requests"]
            dts = _step_times(document, args.replay)
            times, why = None, "the recording ended"
        else:
            start = args.start or next(n.name for n in graph.nodes if n.cyclic)
            params, _ = node_assignments(args.set, graph.node(start))
            fps, mode = args.fps, args.mode
            script = []
            for entry in args.at:
                if len(entry) < 2:
                    raise ValueError(f"--at needs a time and a node, got {' '.join(entry)!r}")
                when = at_time(entry)
                node = graph.node(entry[1])
                values, budget = node_assignments(entry[2:], node)
                script.append((when, {"node": node.name, "params": values, "budget": budget}))
            if args.seconds is not None:
                steps = frame_steps(args.seconds, fps, f"--seconds {args.seconds:g}")
            else:
                last = max((when for when, _ in script), default=0.0)
                steps = frame_steps(last + 4.0, fps, f"{last + 4.0:g} s (4 s after the last --at; --seconds to "
                                    "change it)")
            # a request past the end keeps a frame past it (its time * fps may not even be a number of frames)
            requests = [{"frame": int(round(min(when * fps, steps + 1.0))), **request}
                        for when, request in script]
            dts = None
            times, why = [when for when, _ in script], "--seconds ended the play"
        if args.frames:
            open_frames(args.frames)
        faces = graph.nodes[0].space.faces
        log = []

        def on_frame(k, frame):
            if args.frames:
                write_obj(args.frames / f"frame_{k:05d}.obj", frame.vertices, faces, precision=6)
            log.append({"time": round(frame.time, 4), "node": frame.node, "phase": round(frame.phase, 4),
                        "target": frame.target, "progress": None if frame.progress is None else round(frame.progress, 3),
                        "root": np.round(frame.root_position, 4).tolist(),
                        "heading_deg": round(float(np.degrees(frame.heading)), 3), "events": frame.events})

        try:
            player, digest, answers = perform(graph, start=start, params=params, fps=fps, steps=steps, mode=mode,
                                              requests=requests, on_frame=on_frame, dts=dts)
        except GraphError as exc:
            raise ValueError(f"--replay {args.replay}: {exc}" if args.replay else str(exc)) from None
        root = np.array([entry["root"] for entry in log])
        travelled = float(np.sum(np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1)))
        events = [{"time": e["time"], "event": ev} for e in log for ev in e["events"]]
        # the start's parameters out of reach: clamped and said, as any request's are
        notes = [f"{note_time(0.0)}: start {start}: {player.start_clamped}"] if player.start_clamped else []
        # requests the play never reached (perform answers them in frame order): said, not dropped silently
        for i in sorted(range(len(requests)), key=lambda i: requests[i]["frame"])[len(answers):]:
            r = requests[i]
            values = {**(r.get("params") or {}), **({"budget": r["budget"]} if r.get("budget") is not None else {})}
            asked = " ".join([str(r.get("node") or "set")] + [f"{k}={_number(v)}" for k, v in values.items()])
            at = _seconds(r["frame"], fps) if times is None else times[i]
            notes.append(f"{note_time(at)}: {asked} not applied: {why} at {log[-1]['time']:.2f} s")
        report = {"graph": graph.name, "mode": mode, "fps": fps, "seconds": log[-1]["time"], "frames": len(log),
                  "path_length_m": travelled, "requests": answers, "events": events, "end": log[-1],
                  "notes": notes, "frames_sha256": digest, "timeline": log[:: max(1, len(log) // 50)]}
        if args.replay:
            report["replayed"] = args.replay.name
            # a browser recording has no digest (the page saw the stream's frames, not these bytes)
            report["identical"] = None if document.get("frames_sha256") is None else digest == document["frames_sha256"]
        if args.record:
            doc = recording(graph, player, start=start, params=params, fps=fps, steps=steps, mode=mode, digest=digest)
            args.record.parent.mkdir(parents=True, exist_ok=True)
            args.record.write_text(json.dumps(doc, indent=2) + "\n")
            report["recorded"] = str(args.record)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"{report['graph']}: played {report['seconds']:.2f} s ({report['frames']} frames, {mode}) from {start}, "
              f"travelled {travelled:.2f} m")
        for answer in answers:
            if answer["status"] == "planned":
                print(f"  t {answer['frame'] / fps:6.2f} s  request {answer['node']}: via {' -> '.join(answer['route'])}, "
                      f"leave in {answer['leave_in']:.2f} s, blend {answer['length']:.2f} s, enter at phase "
                      f"{answer['enter_phase']:.2f} (seam {1000 * answer['dissimilarity']:.0f} mm)")
            else:
                print(f"  t {answer['frame'] / fps:6.2f} s  request {answer['node']}: {answer['status']}")
            if answer.get("clamped"):
                print(f"    note: {answer['message']}")
            if answer.get("dropped"):   # as the stream's `superseded` notice
                print(f"    note: replaces the request {answer['dropped']} before it (dropped before it was carried out)")
        for event in events:
            print(f"  t {event['time']:6.2f} s  {event['event']}")
        for note in notes:
            print(f"  note: {note}")
        end = report["end"]
        print(f"  end: {end['node']} at phase {end['phase']:.2f}, root {end['root'][0]:+.2f}, {end['root'][2]:+.2f} m, "
              f"heading {end['heading_deg']:+.1f} deg")
        print(f"  frames sha256 {digest[:16]}...")
        if args.replay:
            said = {True: "identical frames", False: "DIFFERENT frames",
                    None: "no frames digest recorded (a browser recording, or one written without it), nothing "
                          "to compare"}
            print(f"  replay of {args.replay}: {said[report['identical']]}")
        if args.record:
            print(f"  recorded: {args.record}")
    if args.replay and report["identical"] is False:
        return 1
    return 0


def _read_replay(path, graph):
    """The recording at ``path`` (--replay) checked against ``graph``; a ValueError naming the file says what is
    wrong (not text, not JSON, not a recording of this graph, more frames than a play makes)."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"--replay {path}: not a text file (a JSON recording)") from None
    except OSError as exc:
        raise ValueError(f"--replay {path}: {exc.strerror or exc}") from None
    try:
        document = read_recording(json.loads(text), graph)
    except json.JSONDecodeError as exc:
        raise ValueError(f"--replay {path}: not JSON: {exc}") from None
    except GraphError as exc:
        raise ValueError(f"--replay {path}: {exc}") from None
    if not math.isfinite(_seconds(document["fps"], 1.0)):
        raise ValueError(f"--replay {path}: recording: fps must be a finite number of frames per second")
    if document["steps"] + 1 > MAX_FRAMES:
        raise ValueError(f"--replay {path}: recording: {document['steps'] + 1} frames; at most {MAX_FRAMES} per "
                         "play")
    return document


def _number(value):
    return f"{value:g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else repr(value)


def _seconds(frame, fps):
    """``frame / fps`` as a float, inf for a JSON integer too large for one."""
    try:
        return float(frame) / fps
    except OverflowError:
        return math.inf


def _step_times(document, path):
    """The seconds of every step of a recording with ``times`` (a browser recording), else None."""
    from engine.export.performance import ClipError, step_times

    try:
        dts, _ = step_times(document)
    except ClipError as exc:
        raise ValueError(f"--replay {path}: {exc}") from None
    return None if document.get("times") is None else dts

"""What a job does: ingest, align, build and graph, as functions of a JSON payload.

The same functions run in a local worker process (server/jobs/worker.py) and on a Dask worker
(``dask_entry``). A payload is plain JSON::

    {"id": ..., "kind": "build", "attempt": 1, "params": {... the validated request ...},
     "data_dir": "/srv/data", "staging": "/srv/data/work/jobs/<id>/attempt-1-<run>"}

A task writes only inside ``staging`` and returns a result whose ``output`` names what the
server then renames into ``spaces/`` or ``datasets/`` (``publish``): a cancelled or failed job
never leaves a partial space or dataset. Progress goes through a ``Reporter``
(``progress(stage, done, total)``, ``log(line)``), which also notices a cancellation (the file
``staging/../CANCEL``, or the staging directory removed by the server) at the next progress call.
Every run of a job has its own staging directory (``<run>`` is new each time the server starts
the job), so a run the server has left behind (a Dask task it could not stop) never writes into
the directory of the run that replaced it, and stops when it finds its own directory gone.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import os
import shutil
import time
import traceback
from pathlib import Path


# Share of the whole job per stage, in the order the stages run; unknown stages keep the level.
STAGES = {
    "build": [("read", 0.05), ("tetrahedralise", 0.25), ("time-warp", 0.05), ("decompose", 0.3), ("hybrid", 0.15),
              ("parameters", 0.17), ("write", 0.03)],
    "align": [("read", 0.05), ("histograms", 0.13), ("dissimilarity", 0.05), ("root", 0.02), ("trial", 0.06),
              ("race", 0.35), ("align", 0.2), ("repair", 0.06), ("write", 0.08)],
    "ingest": [("validate", 0.75), ("write", 0.25)],
    "export": [("play", 0.4), ("write", 0.6)],
    "graph": [("windows", 0.75), ("edges", 0.2), ("write", 0.05)],
}


class JobCancelled(Exception):
    """The job was asked to stop."""


class JobError(Exception):
    """A job failed for a reason its user can act on (the message says which)."""


class Reporter:
    """Turns ``(stage, done, total)`` into the job's overall progress and sends it with ``emit``.

    ``emit(message)`` gets dicts: ``{"t": "progress", "stage", "progress"}`` (at most every
    ``interval`` seconds, and at every stage change) and ``{"t": "log", "line"}``.
    """

    def __init__(self, kind, emit, staging=None, interval=0.2):
        self.emit, self.staging, self.interval = emit, staging, interval
        self.cancel_file = os.path.join(staging, "..", "CANCEL") if staging is not None else None
        self.bases, base = {}, 0.0
        for stage, weight in STAGES[kind]:
            self.bases[stage] = (base, weight)
            base += weight
        self.stage, self.level, self.sent_at, self.checked_at = None, 0.0, 0.0, 0.0
        self.seen = set()

    def check(self):
        """Raise JobCancelled when the job was cancelled: its cancel file exists, or its staging
        directory is gone. The server removes that directory as soon as the run ends on its side
        (a cancel, a clean stop, a new run of the job), so on Dask, where the server cannot stop
        the task itself, the cancel file may be gone before the task looks (it then went on to
        the end of the build, its sub-tasks keeping the cluster busy)."""
        now = time.monotonic()
        if self.cancel_file is not None and now - self.checked_at > 0.25:
            self.checked_at = now
            if os.path.exists(self.cancel_file):
                raise JobCancelled("cancelled by request")
            if not os.path.isdir(self.staging):
                raise JobCancelled("cancelled: the server ended this run of the job (its staging directory is gone)")

    def progress(self, stage, done=0, total=None):
        self.check()
        if stage in self.bases:
            base, weight = self.bases[stage]
            if total:
                fraction = min(max(done / total, 0.0), 1.0)
            else:  # unknown length (e.g. the hybrid's bisection): approach the end of the stage
                fraction = 1.0 - 0.85 ** max(done or 0, 0)
            self.level = max(self.level, base + weight * fraction)
        now = time.monotonic()
        if stage != self.stage or now - self.sent_at >= self.interval:
            if stage not in self.seen:
                self.seen.add(stage)
                self.log(f"stage {stage}")
            self.stage, self.sent_at = stage, now
            self.emit({"t": "progress", "stage": stage, "progress": round(min(self.level, 0.999), 4)})

    def log(self, line):
        self.emit({"t": "log", "line": str(line)})


def _relative(text, data_dir):
    """Messages name files relative to the data directory (the API never shows server paths)."""
    prefix = str(Path(data_dir)) + os.sep
    return str(text).replace(prefix, "")


def run_task(payload, reporter, runner=None):
    """Run the job ``payload`` describes; returns its JSON result. Raises JobError, JobCancelled.

    ``runner`` (``engine.tasks``; on Dask a ``server.jobs.dask_runner.DaskRunner``) runs the
    split stages of align and build as tasks; None runs them here. The result is the same."""
    kind = payload["kind"]
    if not Path(payload["staging"]).is_dir():  # the server made it; gone means this run was ended
        raise JobCancelled("cancelled: the server ended this run of the job (its staging directory is gone)")
    if kind == "ingest":
        from server.jobs.ingest import run_ingest as run
    elif kind == "export":
        from server.exports import run_export as run
    else:
        run = {"build": functools.partial(run_build, runner=runner), "align": functools.partial(run_align, runner=runner),
               "graph": run_graph}[kind]
    try:
        return run(payload, reporter)
    except (JobCancelled, JobError):
        raise
    except (ValueError, OSError, KeyError) as exc:
        from engine.mesh_io import MeshError

        if isinstance(exc, KeyError) and not isinstance(exc, MeshError):
            raise JobError(f"missing field {exc} in an input file") from exc
        raise JobError(_relative(exc, payload["data_dir"])) from exc


# --- build ----------------------------------------------------------------------------------------
def _toml(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=True)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to a spec")


def spec_toml(spec, captures, name):
    """The TOML spec ``morphspace build`` reads, for a JSON spec (models.BuildSpec) over a dataset."""
    lines = [f"name = {_toml(name)}", f"captures = {_toml(str(captures))}"]
    for key in ("epsilon_mm", "phases", "rest"):
        if spec.get(key) is not None:
            lines.append(f"{key} = {_toml(spec[key])}")
    lines.append(f"sources = {_toml(list(spec['sources']))}")
    if spec.get("parameters"):
        lines.append("[parameters]")
        for key, value in spec["parameters"].items():
            if value is not None:
                lines.append(f"{key} = {_toml(value)}")
    return "\n".join(lines) + "\n"


def check_build_sources(dataset_dir, spec):
    """Each source must be a sequence of the dataset with consistent frames (else align first),
    and the sources all cyclic or all one-shot."""
    cyclic = {}
    for source in spec["sources"]:
        base = Path(dataset_dir) / "sequences" / source
        if not base.is_dir():
            have = sorted(p.name for p in (Path(dataset_dir) / "sequences").iterdir()) \
                if (Path(dataset_dir) / "sequences").is_dir() else []
            raise JobError(f"dataset {Path(dataset_dir).name!r} has no sequence {source!r} "
                           f"(it has {', '.join(have) or 'none'})")
        if not (base / "consistent").is_dir():
            raise JobError(f"sequence {source!r} of dataset {Path(dataset_dir).name!r} has no consistent-topology "
                           "frames (its frames are unstructured): run an align job on the dataset first")
        if not (base / "meta.json").is_file():
            raise JobError(f"sequence {source!r} of dataset {Path(dataset_dir).name!r} has no meta.json")
        with contextlib.suppress(OSError, ValueError, AttributeError):  # unreadable: the build says so
            cyclic[source] = bool(json.loads((base / "meta.json").read_text()).get("cyclic", False))
    if len(set(cyclic.values())) > 1:
        loops = sorted(name for name, c in cyclic.items() if c)
        once = sorted(name for name, c in cyclic.items() if not c)
        raise JobError(f"sources must be all cyclic or all non-cyclic: {', '.join(loops)} cyclic, "
                       f"{', '.join(once)} not")


def run_build(payload, reporter, runner=None):
    from engine.motion_space import build_motion_space
    from server.commands.build import choose_rest, load_sources, read_spec, sources_to_metres
    from server.units import say_conventions, source_metadata

    params, staging = payload["params"], Path(payload["staging"])
    dataset_dir = Path(payload["data_dir"]) / "datasets" / params["dataset"]
    if not dataset_dir.is_dir():
        raise JobError(f"no dataset {params['dataset']!r}")
    check_build_sources(dataset_dir, params["spec"])
    spec_path = staging / "spec.toml"
    spec_path.write_text(spec_toml(params["spec"], dataset_dir, params["space"]))
    spec = read_spec(spec_path)
    started = time.perf_counter()
    try:
        clips, faces = load_sources(spec["directories"], fps=30.0, cyclic=False, progress=reporter.progress,
                                    log=reporter.log)
        rest, note, turn = choose_rest(clips, faces, spec["rest"], dataset_dir / "template" / "body.obj")
        clips, rest, conventions = sources_to_metres(clips, rest, spec["directories"])  # units and up: auto
    except ValueError as exc:
        raise JobError(str(exc).replace(str(dataset_dir) + "/", "")) from None
    reporter.log(note.replace(str(dataset_dir) + "/", ""))
    if turn is not None:
        reporter.log(f"heading 0: the aligned capture's travel, {math.degrees(turn):+.1f} degrees from the rest's facing")
    say_conventions(conventions, [clip.name for clip in clips] + ["the rest shape"], reporter.log, what="source")
    out = staging / f"{params['space']}.mspace"
    epsilon_mm = spec["epsilon_mm"] or 5.0
    report = build_motion_space(out, clips, faces, name=params["space"], n_phases=spec["phases"],
                                epsilon=epsilon_mm / 1000.0, rest=rest, parameters=spec["parameters"],
                                metadata=source_metadata([clip.name for clip in clips], conventions[:-1],
                                                         conventions[-1]),
                                progress=reporter.progress, runner=runner, heading_turn=turn)
    reporter.progress("write", 1, 1)
    hybrid = report["hybrid"]
    reporter.log(f"built {params['space']}: {report['n_sources']} sources x {report['n_phases']} phases, "
                 f"{report['n_vertices']} vertices, {report['n_tets']} tets in {time.perf_counter() - started:.1f} s")
    summary = {"space": params["space"], "n_sources": report["n_sources"], "n_phases": report["n_phases"],
               "n_vertices": report["n_vertices"], "n_tets": report["n_tets"], "epsilon_mm": epsilon_mm,
               "hybrid_references": hybrid["references"], "hybrid_max_test_error_mm": 1000 * hybrid["max_test_error"],
               "hybrid_max_check_error_mm": (None if hybrid.get("max_check_error") is None
                                             else 1000 * hybrid["max_check_error"]),
               "source_units": report["source_units"], "source_up": report["source_up"],
               "seconds": round(time.perf_counter() - started, 2), "stage_seconds": report["timings"]}
    if report.get("parameters"):
        p = report["parameters"]
        summary["parameters"] = [{"name": n, "unit": u, "min": lo, "max": hi}
                                 for n, u, (lo, hi) in zip(p["names"], p["units"], p["domain"], strict=True)]
    return {"output": {"type": "space", "name": params["space"], "path": out.name}, "summary": summary}


# --- graph ----------------------------------------------------------------------------------------
def run_graph(payload, reporter):
    from engine.graph import GraphError, NodeSpec, WindowOptions, build_graph
    from server.commands.build_graph import WINDOW_KEYS

    params, staging = payload["params"], Path(payload["staging"])
    spaces = Path(payload["data_dir"]) / "spaces"
    nodes = []
    for node in params["nodes"]:
        file = spaces / f"{node['space']}.mspace"
        if not file.is_file():
            raise JobError(f"node {node['name']!r}: no space {node['space']!r}")
        nodes.append(NodeSpec(node["name"], file, node.get("return_to")))
    options = WindowOptions(**{WINDOW_KEYS[k]: v for k, v in params["window"].items()})
    out = staging / f"{params['graph']}.mgraph"
    try:
        report = build_graph(out, nodes, [tuple(e) for e in params["edges"]], name=params["graph"], options=options,
                             progress=reporter.progress, relative_to=spaces)
    except GraphError as exc:
        raise JobError(_relative(exc, payload["data_dir"])) from None
    reporter.progress("write", 1, 1)
    reporter.log(f"built graph {params['graph']}: {len(report['nodes'])} nodes, {len(report['edges'])} edges "
                 f"in {report['build_s']:.1f} s")
    summary = {"graph": params["graph"], "nodes": [n["name"] for n in report["nodes"]],
               "edges": [{"from": e["from"], "to": e["to"], "best_seam_mm": round(1000 * e["min_m"], 2)}
                         for e in report["edges"]], "seconds": report["build_s"]}
    return {"output": {"type": "graph", "name": params["graph"], "path": out.name}, "summary": summary}


# --- align ----------------------------------------------------------------------------------------
# what a job record made before these parameters existed runs with (the AlignJob model's defaults)
ALIGN_DEFAULTS = {"tree": "mst", "root_choice": "auto", "colors": "auto", "repair_budget": 0.25, "units": "auto",
                  "up": "auto", "swing_limbs": False, "reach_limbs": True, "graft_limbs": False}


def align_sequences(datasets, params):
    """The sequences an align job's ``params`` name (``datasets``, ``only``), as ``align`` reads
    them (an uploaded sequence with only consistent-topology frames is aligned from those)."""
    from server.commands.align_inputs import resolve_inputs

    inputs = []
    for name in params["datasets"]:
        if not (datasets / name).is_dir():
            raise JobError(f"no dataset {name!r}")
        inputs.append(datasets / name)
    return resolve_inputs(inputs, params.get("only"))


def run_align(payload, reporter, runner=None):
    from engine.align import AlignmentOptions, align_captures
    from engine.surface import model_size
    from engine.align.repair import TRUSTED
    from server.commands.align import COLOUR_MODES
    from server.commands.align_inputs import DEFAULT_FPS, convert_inputs, parse_root, read_inputs
    from server.commands.align_output import (confidence_summary, options_record, root_trial_text, stopped_text,
                                              write_alignment)
    from server.units import common_convention, count_text, display_unit

    params, staging = {**ALIGN_DEFAULTS, **payload["params"]}, Path(payload["staging"])
    sequences = align_sequences(Path(payload["data_dir"]) / "datasets", params)
    started = time.perf_counter()
    meshes, lengths = read_inputs(sequences, reporter.progress, say=reporter.log)
    reporter.log(f"read {count_text(int(lengths.sum()), 'frame')} of {count_text(len(sequences), 'sequence')}")
    meshes, conventions = convert_inputs(meshes, sequences, lengths, params["units"], params["up"], say=reporter.log)
    root = parse_root(params.get("root"), sequences, lengths, label="root")
    options = AlignmentOptions(patches=params["patches"], levels=params["levels"],
                               swing_limbs=params["swing_limbs"], reach_limbs=params["reach_limbs"],
                               graft_limbs=params["graft_limbs"])
    result = align_captures(meshes, lengths, method="sequential" if params["sequential"] else "tree",
                            tree_kind=params["tree"], root=root, root_choice=params["root_choice"],
                            options=options, window=params["window"], workers=1, retries=params["retries"],
                            use_colors=COLOUR_MODES[params["colors"]],
                            seed=params["seed"], repair_budget=params["repair_budget"],
                            progress=reporter.progress, runner=runner)
    out = staging / "dataset"
    out.mkdir()
    fps = float((sequences[0].get("meta") or {}).get("fps", DEFAULT_FPS))
    write_alignment(out, sequences, meshes, lengths, result, fps=fps,
                    options_record=options_record(params, result.colour_cues),
                    progress=reporter.progress, conventions=conventions)
    aligned = result.aligned
    size = model_size(aligned.root_vertices)
    reporter.log(f"aligned {int(lengths.sum())} frames in {time.perf_counter() - started:.1f} s")
    if result.root_trial:
        reporter.log(root_trial_text(result.root_trial, int(result.aligned.root), sequences, lengths))
    if result.root_reason:
        reporter.log(f"root: {result.root_reason}")
    confidence = confidence_summary(aligned, sequences, lengths)
    reporter.log(f"confidence: {count_text(confidence['repaired_frames'], 'frame')} repaired "
                 f"({count_text(confidence['repair_alignments'], 'alignment')} tried{stopped_text(confidence)}), "
                 f"{confidence['flagged_frames']} of "
                 f"{int(lengths.sum())} still below {TRUSTED} (the summary's flagged lists them per sequence), "
                 f"{confidence['pulled_frames']} with a limb pulled onto what nothing covered")
    return {"output": {"type": "dataset", "name": params["output"], "path": out.name},
            "summary": {"dataset": params["output"], "frames": int(lengths.sum()),
                        "sequences": [s["name"] for s in sequences], "root": int(aligned.root),
                        "residual_mean_mm": float(1000 * aligned.residual.mean()),
                        "residual_max_mm": float(1000 * aligned.residual_max.max()),
                        "residual_mean_pct": float(100 * aligned.residual.mean() / size),
                        "residual_max_pct": float(100 * aligned.residual_max.max() / size),
                        "input": {s["name"]: c.to_metadata() for s, c in zip(sequences, conventions)},
                        "display_unit": display_unit(common_convention(conventions)), **confidence,
                        "root_trial": result.root_trial, "root_reason": result.root_reason,
                        "seconds": round(time.perf_counter() - started, 2)}}


# --- publishing (done by the server, after the task) ------------------------------------------------
def publish(result, staging, data_dir, replace):
    """Rename the task's output into ``spaces/``, ``datasets/`` or ``exports/``; returns the job's public result."""
    from server.uploads import UploadError, publish_dir

    output = result["output"]
    source = Path(staging) / output["path"]
    if output["type"] in ("space", "graph"):
        suffix = ".mspace" if output["type"] == "space" else ".mgraph"
        target = Path(data_dir) / "spaces" / f"{output['name']}{suffix}"
        if target.exists() and not replace:
            raise JobError(f"{output['type']} {output['name']!r} appeared while the job ran; pass replace=true "
                           "to replace it")
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(source, target)
        url = f"/v1/{'spaces' if output['type'] == 'space' else 'graphs'}/{output['name']}"
    elif output["type"] == "export":  # named by the job's id: never replaces another
        target = Path(data_dir) / "exports" / output["name"]
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(source, target)
        url = f"/v1/exports/{output['name']}"
    else:
        target = Path(data_dir) / "datasets" / output["name"]
        try:
            publish_dir(source, target, replace=replace)
        except UploadError as exc:
            raise JobError(exc.message) from None
        url = f"/v1/datasets/{output['name']}"
    return {**result["summary"], "url": url}


# --- Dask --------------------------------------------------------------------------------------------
def dask_entry(payload_json, topic):
    """Run a job on a Dask worker: JSON in, JSON out; progress and log as worker events on ``topic``.

    Returns ``{"result": ...}``, ``{"cancelled": message}`` or ``{"error": message, "traceback": ...}``
    as a JSON string (exceptions are not shipped back through Dask's pickling).
    """
    from distributed import get_worker

    from server.jobs.dask_runner import DaskRunner

    payload = json.loads(payload_json)
    worker = get_worker()

    def emit(message):
        try:
            worker.log_event(topic, message)
        except Exception:  # noqa: BLE001 - progress is best effort; the job goes on
            pass

    reporter = Reporter(payload["kind"], emit, staging=payload["staging"])
    emit({"t": "worker", "info": {"address": worker.address, "pid": os.getpid()}})
    try:
        # the split stages as tasks on this cluster; they stop when this run's staging directory goes
        runner = DaskRunner(topic, check=reporter.check, log=reporter.log, alive=payload["staging"])
        return json.dumps({"result": run_task(payload, reporter, runner)})
    except JobCancelled as exc:
        shutil.rmtree(payload["staging"], ignore_errors=True)
        return json.dumps({"cancelled": str(exc)})
    except JobError as exc:
        return json.dumps({"error": str(exc)})
    except Exception as exc:  # noqa: BLE001 - reported to the job record, with the traceback in its log
        return json.dumps({"error": f"{type(exc).__name__}: {_relative(exc, payload['data_dir'])}",
                           "traceback": _relative(traceback.format_exc(), payload["data_dir"])})

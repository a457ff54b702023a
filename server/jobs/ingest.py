"""The ingest job: a dataset read with engine.mesh_io and written normalised (see run_ingest)."""

from __future__ import annotations

import json
import time
from pathlib import Path

from server.jobs.tasks import JobError


def _json_file(path):
    """The JSON object in ``path``, or {} when it is missing, unreadable or not an object."""
    try:
        value = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}


def run_ingest(payload, reporter):
    """Read every frame (engine.mesh_io), rewrite each sequence as frame_0000.obj ... in natural
    order, complete meta.json (frames, duration, topology, source frame names, the units and up
    axis the files are in), add template/body.obj from the first consistent frame when the
    dataset has none, new manifest (the template's units and up axis, its model size in metres).
    The files are not converted: units and axes are decided as ``morphspace build --units auto
    --up auto`` decides them (the geometry, then what the metadata says) and recorded."""
    import numpy as np

    from engine.mesh_io import MeshError, list_frames, read_mesh, write_obj
    from engine.mesh_io.dataset import write_capture_manifest
    from engine.mesh_io.mesh_file import mesh_file_type
    from engine.surface import model_size
    from server.uploads import KINDS, FrameStats, sequence_meta
    from server.units import decide_convention, declared_convention

    params, staging = payload["params"], Path(payload["staging"])
    source = Path(payload["data_dir"]) / "datasets" / params["dataset"]
    if not (source / "sequences").is_dir():
        raise JobError(f"dataset {params['dataset']!r} has no sequences/ folder")
    groups = []
    for seq in sorted(p.name for p in (source / "sequences").iterdir() if p.is_dir()):
        for kind in KINDS:
            if (source / "sequences" / seq / kind).is_dir():
                groups.append((seq, kind, list_frames(source / "sequences" / seq / kind)))
    total = sum(len(frames) for _, _, frames in groups)
    if total == 0:
        raise JobError(f"dataset {params['dataset']!r} has no frames")
    out = staging / "dataset"
    uploaded_body = _json_file(source / "manifest.json").get("body")
    done, metas, template, warnings = 0, {}, None, []
    for seq, kind, frames in groups:
        stats = FrameStats()
        base = source / "sequences" / seq
        sampled = set(np.linspace(0, len(frames) - 1, min(len(frames), 16)).round().astype(int).tolist())
        samples = []  # a few frames' vertices: what the units and up axis are decided on
        for k, frame in enumerate(frames):
            label = f"{params['dataset']}/sequences/{seq}/{kind}/{frame}"
            try:
                mesh = read_mesh(base / kind / frame, name=label)
            except MeshError as exc:
                raise JobError(str(exc)) from None
            stats.add(mesh, label)
            if k in sampled:
                samples.append(mesh.vertices)
            write_obj(out / "sequences" / seq / kind / f"frame_{k:04d}.obj", mesh.vertices, mesh.faces,
                      colors=mesh.colors)  # exact: the coordinates as read, to the last bit
            done += 1
            reporter.progress("validate", done, total)
        if kind == "consistent" and not stats.consistent:
            raise JobError(f"{stats.first_problem}; frames in consistent/ must share one mesh structure")
        if kind == "consistent" and template is None:
            template = read_mesh(out / "sequences" / seq / kind / "frame_0000.obj")
        try:
            meta = json.loads((base / "meta.json").read_text())
        except (OSError, ValueError):
            meta = {}
            warnings.append(f"sequence {seq}: no readable meta.json; assumed 30 fps, not cyclic")
        meta.setdefault("fps", 30.0)
        meta.setdefault("cyclic", False)
        declared = declared_convention([meta, uploaded_body])
        convention = decide_convention(samples, declared=declared)
        meta.update(units=convention.units, up=convention.up_label, input=convention.to_metadata())
        warnings += [f"sequence {seq}: {warning}" for warning in convention.warnings]
        reporter.log(f"sequence {seq} ({kind}, {stats.frames} frames): {convention.describe()}")
        record = sequence_meta(seq, meta, kind, stats)
        record["source_frames"] = frames
        if seq in metas:  # both kinds: keep the consistent record, note the other
            metas[seq][f"{kind}_frames"] = stats.frames
        else:
            metas[seq] = record
    reporter.progress("write", 0, 1)
    for seq, record in metas.items():
        (out / "sequences" / seq / "meta.json").write_text(json.dumps(record, indent=2) + "\n")
    if (source / "template").is_dir():
        for path in sorted((source / "template").iterdir()):
            if mesh_file_type(path.name) is None:  # a textured template's .mtl and images: read with it
                continue
            try:
                mesh = read_mesh(path, name=f"{params['dataset']}/template/{path.name}")
            except MeshError as exc:
                raise JobError(str(exc)) from None
            write_obj(out / "template" / f"{path.stem}.obj", mesh.vertices, mesh.faces, colors=mesh.colors)
    if not (out / "template" / "body.obj").exists() and template is not None:
        write_obj(out / "template" / "body.obj", template.vertices, template.faces, colors=template.colors)
        reporter.log("template/body.obj: the first consistent frame (the rest shape builds use)")
    body = {}
    template_path = out / "template" / "body.obj"
    if template_path.exists():
        template = read_mesh(template_path)
    if template is not None:
        declared = declared_convention([uploaded_body])
        convention = decide_convention([template.vertices], declared=declared)
        body = {"vertices": int(len(template.vertices)), "faces": int(len(template.faces)),
                "model_size": float(model_size(template.vertices)) / convention.per_metre,
                "units": convention.units, "up": convention.up_label, "input": convention.to_metadata()}
        reporter.log(f"template/body.obj: {convention.describe()}")
    write_capture_manifest(out, {"uploaded": True, "ingested": True, "created": time.time(), "body": body,
                                 "sequences": list(metas.values()), "warnings": warnings})
    reporter.progress("write", 1, 1)
    for line in warnings:
        reporter.log(line)
    name = params.get("output") or params["dataset"]
    return {"output": {"type": "dataset", "name": name, "path": out.name},
            "summary": {"dataset": name, "frames": total, "sequences": list(metas), "warnings": warnings}}

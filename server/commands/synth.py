"""Generate synthetic performance captures with ground truth.

Writes a capture dataset (see docs/file-formats.md): for every sequence of the preset, the
consistent-topology frames, independently re-meshed "unstructured" frames, the ground truth
(root trajectory, joints, template vertex positions) and the requested and measured parameters,
plus preview pictures. The ``studio`` presets use a real body (MakeHuman) and real motion (CMU)
and reconstruct every frame like a multi-view studio (merged contacts, holes, fragments, noise;
some sequences written in millimetres and/or Z up). Examples:

    morphspace synth --preset demo --out data/captures/demo
    morphspace synth --preset studio --out data/captures/studio
"""

from __future__ import annotations

import math
import multiprocessing
import os
import queue
import time
from concurrent.futures import ProcessPoolExecutor
from functools import lru_cache
from pathlib import Path

import numpy as np
from tqdm import tqdm

from engine.mesh_io.dataset import (
    write_capture_manifest,
    write_capture_sequence,
    write_capture_template,
)
from engine.synthetic import PRESETS, build_body, generate_sequence_data, get_preset
from engine.synthetic.body import MAX_VERTICES, MIN_VERTICES
from engine.synthetic.studio import StudioPreset
from server.commands.checks import check_output_path
from server.commands.staging import staged
from server.units import count_text

MAX_FPS = 240.0  # frames per second of a synthetic capture (a fast studio camera)
MAX_NOISE_MM = 100.0


def add_arguments(parser):
    parser.add_argument("--preset", default="demo", choices=sorted(PRESETS), help="capture set (default demo)")
    parser.add_argument("--out", required=True, type=Path, help="output dataset directory")
    parser.add_argument("--vertices", type=int, help="body vertex count, 1000..50000 (preset default); for the "
                        "studio presets, the vertex count of each reconstructed frame")
    parser.add_argument("--height", type=float, help="body height in metres (procedural presets; default 1.75)")
    parser.add_argument("--fps", type=float, help="frames per second (preset default)")
    parser.add_argument("--noise-mm", type=float, help="reconstruction noise of unstructured frames, mm")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="generate only these sequences")
    parser.add_argument("--no-unstructured", action="store_true", help="skip the re-meshed frames")
    parser.add_argument("--consistent-format", choices=("obj", "ply"),
                        help="consistent frames as obj (default) or ply (default for the studio presets)")
    parser.add_argument("--unstructured-format", choices=("obj", "ply"), default="ply")
    parser.add_argument("--textured", action="store_true",
                        help="write the re-meshed frames' colours as a texture atlas beside each frame (an image, "
                             "and for OBJ a material library) instead of vertex colours, as studios deliver them")
    parser.add_argument("--no-previews", action="store_true", help="skip the preview pictures")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="worker processes (default: up to 2)")
    parser.add_argument("--force", action="store_true", help="replace an existing output directory")


@lru_cache(maxsize=2)
def _body(vertices, height):
    return build_body(vertices, height)


_PROGRESS = None


def _init_worker(progress_queue):
    global _PROGRESS
    _PROGRESS = progress_queue


def _generate(job):
    """Worker: generate, write and preview one sequence; returns its metadata."""
    body = _body(job["vertices"], job["height"])
    spec = job["spec"]

    def progress(done, total):
        report(spec.name, done, total)

    # Progress in frame units: re-meshing counts one per frame, writing two (both versions).
    data = generate_sequence_data(body, spec, fps=job["fps"], noise_mm=job["noise_mm"], seed=job["seed"],
                                  unstructured=job["unstructured"],
                                  progress=lambda done, total: progress(done, 3 * total))
    frames = len(data["vertices"])
    offset = frames if job["unstructured"] else 0
    write_capture_sequence(
        job["root"], spec.name, faces=body.F, vertices=data["vertices"], colors=body.colors,
        unstructured=data["unstructured"], truth=data["truth"], meta=data["meta"],
        consistent_format=job["consistent_format"], unstructured_format=job["unstructured_format"],
        textured=job["textured"], progress=lambda done, total: progress(offset + done, offset + total))
    if job["previews"]:
        _write_preview(Path(job["root"]) / "previews" / f"{spec.name}.png", body, data)
    return data["meta"]


def _write_preview(path, body, data):
    from PIL import Image

    from engine.render import render_meshes

    V = data["vertices"]
    picks = np.linspace(0, len(V) - 1, min(8, len(V))).astype(int)
    meta = data["meta"]
    turning = meta["kind"] == "gait" and abs(meta["requested"].get("turn_rate", 0.0)) > 0
    azimuth = 90.0 if meta["kind"] in ("gait", "jump") and not turning else 35.0
    elevation = 55.0 if turning else 10.0  # from above, to show the curved path
    strip = render_meshes([(V[k], body.F, body.colors) for k in picks], azimuth=azimuth, elevation=elevation,
                          width=1400, height=520,
                          title=f"{data['meta']['name']}: frames {', '.join(str(k) for k in picks)}")
    images = [strip]
    if data["unstructured"]:
        rng = np.random.default_rng(0)
        Vu, Fu, _ = data["unstructured"][len(V) // 2]
        face_colors = rng.uniform(0.3, 1.0, (len(Vu), 3))
        tri = render_meshes([(V[len(V) // 2], body.F, body.colors), (Vu + np.array([0.9, 0, 0]), Fu, face_colors)],
                            azimuth=0.0, elevation=5, width=1400, height=520,
                            title="middle frame: consistent topology (left), unstructured re-mesh (right)")
        images.append(tri)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(images, axis=0)).save(path)


def report(name, done, total):
    """In a worker: tell the parent's progress bar that ``done`` of ``total`` units of ``name`` are done."""
    if _PROGRESS is not None:
        _PROGRESS.put((name, done, total))


def select_sequences(preset, only):
    """The preset's sequence specs, or only the named ones (a ValueError names unknown ones)."""
    specs = list(preset.sequences)
    if only:
        known = {s.name for s in specs}
        unknown = [n for n in only if n not in known]
        if unknown:
            raise ValueError(f"unknown sequence(s) {', '.join(unknown)} in preset {preset.name}; "
                             f"known: {', '.join(sorted(known))}")
        specs = [s for s in specs if s.name in only]
    return specs


def check_dataset_out(out, force):
    """Refuse an --out that synth or a command like it must not write to, before anything is made: one that
    exists without --force, exists and is not a directory, holds the current directory, or cannot be made."""
    here = Path.cwd()
    if out.resolve() == here or out.resolve() in here.parents:  # (--force would remove it)
        raise ValueError(f"--out {out}: is the current directory or holds it; give a new directory")
    check_output_path(out, "--out", directory=True)
    if out.exists() and not force:
        raise FileExistsError(f"{out} already exists; pass --force to replace it")


def check_options(args):
    """Refuse bad numbers before anything is made (a ValueError naming the option)."""
    if args.fps is not None and not (math.isfinite(args.fps) and 1.0 <= args.fps <= MAX_FPS):
        raise ValueError(f"--fps must be between 1 and {MAX_FPS:g} frames per second, got {args.fps:g}")
    if args.noise_mm is not None and not (math.isfinite(args.noise_mm) and 0 <= args.noise_mm <= MAX_NOISE_MM):
        raise ValueError(f"--noise-mm must be between 0 and {MAX_NOISE_MM:g}, got {args.noise_mm:g}")
    if args.vertices is not None and not MIN_VERTICES <= args.vertices <= MAX_VERTICES:
        raise ValueError(f"--vertices must be between {MIN_VERTICES} and {MAX_VERTICES}, got {args.vertices}")
    most = max(64, os.cpu_count() or 1)
    if not 1 <= args.workers <= most:
        raise ValueError(f"--workers must be between 1 and {most}, got {args.workers}")
    if args.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
    check_dataset_out(args.out, args.force)


def run(args):
    preset = get_preset(args.preset)
    check_options(args)
    if isinstance(preset, StudioPreset):
        from server.commands.synth_studio import run_studio

        return run_studio(args, preset)
    height = 1.75 if args.height is None else args.height
    if not (math.isfinite(height) and 1.0 <= height <= 2.5):
        raise ValueError(f"--height must be between 1.0 and 2.5 m, got {height:g}")
    consistent_format = args.consistent_format or "obj"
    vertices = args.vertices or preset.vertices
    fps = args.fps or preset.fps
    noise_mm = preset.noise_mm if args.noise_mm is None else args.noise_mm
    specs = select_sequences(preset, args.only)
    out = args.out

    started = time.perf_counter()
    with staged(out) as staging:
        body = _body(vertices, height)
        write_capture_template(staging, body)
        jobs = [dict(spec=spec, vertices=vertices, height=height, fps=fps, noise_mm=noise_mm,
                     seed=args.seed * 1000 + i, unstructured=not args.no_unstructured, root=str(staging),
                     consistent_format=consistent_format, unstructured_format=args.unstructured_format,
                     textured=args.textured, previews=not args.no_previews)
                for i, spec in enumerate(specs)]
        with worker_pool(args.workers) as pool:
            results = run_jobs(pool, _generate, jobs)
        metas = {job["spec"].name: meta for job, meta in zip(jobs, results)}
        manifest = {
            "preset": preset.name, "seed": args.seed, "fps": fps, "noise_mm": noise_mm,
            "body": {"vertices": int(len(body.V)), "faces": int(len(body.F)), "height": height,
                     "model_size": body.size, "up": "+Y", "forward": "+Z", "units": "m"},
            "skeleton": body.skeleton.to_dict(),
            "consistent_format": consistent_format,
            "unstructured_format": None if args.no_unstructured else args.unstructured_format,
            "unstructured_textured": bool(args.textured and not args.no_unstructured),
            "sequences": [metas[s.name] for s in specs],
        }
        write_capture_manifest(staging, manifest)
    frames = sum(m["frames"] for m in manifest["sequences"])
    print(f"wrote {count_text(len(specs), 'sequence')}, {frames} frames, body of {len(body.V)} vertices "
          f"to {out} in {time.perf_counter() - started:.1f} s")
    for m in manifest["sequences"]:
        measured = ", ".join(f"{k} {_fixed(v)}" for k, v in m["measured"].items())
        print(f"  {m['name']:<18} {m['frames']:>4} frames  measured: {measured}")
    return 0


class worker_pool:
    """A spawn-context process pool whose workers report progress to the parent (``report``)."""

    def __init__(self, workers):
        context = multiprocessing.get_context("spawn")
        self.queue = context.Queue()
        self.pool = ProcessPoolExecutor(max_workers=max(1, workers), mp_context=context, initializer=_init_worker,
                                        initargs=(self.queue,))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.pool.shutdown(wait=True, cancel_futures=True)
        return False


def _fixed(value):
    """A measured parameter with 3 decimals, never "-0.000" (a turn rate of -1e-9 read as a turn)."""
    text = f"{value:.3f}"
    return "0.000" if text == "-0.000" else text


def run_jobs(pool, function, jobs, desc="synth", total=None, per_job=False, unit="frame"):
    """Run ``function(job)`` for every job on the pool with one progress bar; results in job order.

    Jobs report progress through ``report(name, done, total)``; the bar sums over the names
    (its length is ``total`` when known beforehand, else the sum of the reported totals). With
    ``per_job`` the bar counts finished jobs instead (its length known from the start, where the
    jobs' own totals are not: a sequence's frame count is known once its motion is made), and the
    reports show as the bar's note; else the bar counts ``unit`` and its note is the name last
    reported.
    """
    if per_job:
        total = len(jobs)
    bar = tqdm(total=total or 0, unit="sequence" if per_job else unit, desc=desc, dynamic_ncols=True,
               mininterval=0.5)
    seen = {}
    futures = {pool.pool.submit(function, job): i for i, job in enumerate(jobs)}
    results = [None] * len(jobs)
    pending = set(futures)
    try:
        while pending:
            try:
                name, done, reported = pool.queue.get(timeout=0.2)
                old_done, old_total = seen.get(name, (0, 0))
                if not per_job:
                    if total is None:
                        bar.total += reported - old_total
                    bar.update(done - old_done)
                seen[name] = (done, reported)
                bar.set_postfix_str(f"{name} {done}/{reported}" if per_job else name)
            except queue.Empty:
                pass
            for future in [f for f in pending if f.done()]:
                pending.discard(future)
                results[futures[future]] = future.result()
                if per_job:
                    bar.update(1)
    finally:
        bar.close()
    return results

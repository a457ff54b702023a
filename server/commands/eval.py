"""Measure a motion space's blending: accuracy and speed of each method, heatmaps, epsilon sweep.

Prints a Table I analogue (Casas et al. 2012, section 4.2): maximum and mean per-vertex error
against the non-linear blend over a grid of weights x all phase samples, for linear blending,
hybrid blending with 1 and 3 references, the space's own hybrid (to its epsilon) and non-linear
blending, with the time per frame of each. Writes DIR/heatmap.png (fig. 3) and DIR/results.json;
--sweep rebuilds the hybrid for several epsilons (figs. 5-6, DIR/epsilon_sweep.png); --captures
compares the blends with the synthetic generator's true motion at the in-between speeds.
Example:

    morphspace eval data/spaces/walk_jog.mspace --sweep --captures data/captures/demo
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np

from engine import evaluation
from server.progress import StageBars
from engine.mesh_io.dataset import read_capture_manifest, sequence_dir
from engine.motion_space import MotionSpace
from engine.synthetic import build_body
from server.commands.checks import check_output_path

MAX_TIMING_CALLS = 100_000  # the timing draws its random requests up front: memory grows with the calls


def add_arguments(parser):
    parser.add_argument("space", type=Path, help="motion space file (.mspace)")
    parser.add_argument("--out", type=Path, help="directory for the figures (default: <space stem>-eval/ "
                        "next to the space)")
    parser.add_argument("--json", action="store_true", help="print one JSON object with every figure instead "
                        "of the tables")
    parser.add_argument("--sweep", action="store_true", help="also rebuild the hybrid for each --epsilons-mm")
    parser.add_argument("--epsilons-mm", type=float, nargs="+", default=list(evaluation.EPSILONS_MM),
                        metavar="MM", help="thresholds of the sweep (default 1 2 3 5 8 12 20)")
    parser.add_argument("--captures", type=Path, metavar="DATASET_DIR",
                        help="the capture dataset the sources came from: also compare with the true motion")
    parser.add_argument("--weights", type=float, nargs="+", metavar="W",
                        help="weights of the heatmap pose (default: where the 1-reference hybrid errs most)")
    parser.add_argument("--phase", type=float, help="phase of the heatmap pose in [0, 1]")
    parser.add_argument("--timing-calls", type=int, default=200, help="blend calls timed per method (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the timing's random weights and phases")


def capture_truth(space, dataset):
    """The generator's body and true motion for a space built from a capture dataset's gaits.

    Returns
    -------
    body : Body
    true_motion : callable(weights) -> Motion
    sources : list of dict   per source: name, speed, turn_rate
    """
    dataset = Path(dataset)
    manifest = read_capture_manifest(dataset)
    speeds, turns, fps, sources = [], [], set(), []
    for name in space.source_names:
        path = sequence_dir(dataset, name) / "meta.json"
        if not path.is_file():
            raise ValueError(f"{dataset}: no sequence {name!r} (the space's source) in this dataset")
        meta = json.loads(path.read_text())
        if meta.get("kind") != "gait" or not meta.get("cyclic"):
            raise ValueError(f"{path}: ground truth is only compared for cyclic gaits, {name!r} is a "
                             f"{meta.get('kind')}")
        speeds.append(meta["requested"]["speed"])
        turns.append(meta["requested"].get("turn_rate", 0.0))
        fps.add(float(meta["fps"]))
        sources.append({"name": name, "speed": speeds[-1], "turn_rate": turns[-1]})
    if len(fps) != 1:
        raise ValueError(f"{dataset}: the sources have different frame rates {sorted(fps)}")
    height = manifest["body"].get("height")  # null in datasets synthesised before 2026-11-30: the default
    body = build_body(int(manifest["body"]["vertices"]), *(() if height is None else (float(height),)))
    if len(body.V) != space.n_vertices:
        raise ValueError(f"{dataset}: its body has {len(body.V)} vertices, the space {space.n_vertices}: --captures "
                         "compares a space built from the dataset's own consistent frames (the generator's "
                         "mesh) with its truth; a space built from aligned frames has the root frame's mesh")
    true_motion = evaluation.gait_truth(body, speeds, turn_rates=turns, fps=fps.pop())
    return body, true_motion, sources


def _table(headers, rows):
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]

    def line(cells):  # first column left-aligned, numbers right-aligned
        return "  ".join(str(c).rjust(w) if i else str(c).ljust(w) for i, (c, w) in enumerate(zip(cells, widths)))

    return "\n".join([line(headers), line(["-" * w for w in widths])] + [line(r) for r in rows])


def _print_report(result):
    errors = result["errors"]
    print(f"{errors['space']}: {errors['n_sources']} sources x {errors['n_phases']} phases, "
          f"{errors['n_vertices']} vertices, model size {errors['model_size_m']:.3f} m")
    print(f"error vs non-linear blending over {len(errors['weights'])} weight vectors x "
          f"{len(errors['phases'])} phases; time per frame median of {errors['timing']['calls']} calls "
          f"({errors['timing']['nonlinear_calls']} non-linear), "
          f"{'single-threaded' if errors['timing']['single_threaded'] else 'threads not limited'}")
    rows = []
    for method, m in errors["methods"].items():
        refs = "" if method in ("linear", "nonlinear") else str(m["references"])
        rows.append([m["label"] if method != "hybrid" else f"Hybrid, epsilon {m['epsilon_mm']:g} mm", refs,
                     f"{m['max_error_mm']:.2f}", f"{m['max_error_percent']:.3f}", f"{m['mean_error_mm']:.3f}",
                     f"{m['correction_bytes'] / 1e6:.2f}" if refs else "",
                     f"{m['time_per_frame_ms']:.3f}", f"{m['frames_per_second']:,.0f}"])
    print(_table(["method", "refs", "max mm", "max %", "mean mm", "MB", "ms/frame", "frames/s"], rows))
    sheet = errors.get("sheet")
    if sheet:   # the grid holds blends of sources no parameter reaches; the hybrid's bound is on the sheet
        print(f"(the weights above span every blend of the {errors['n_sources']} sources; on the layout's sheet, "
              f"where parameters lead ({sheet['weights']} weight vectors), the hybrid is within "
              f"{sheet['hybrid']['max_error_mm']:.2f} mm of non-linear blending (epsilon "
              f"{errors['epsilon_mm']:g} mm) and linear blending {sheet['linear']['max_error_mm']:.2f} mm)")
    print(f"heatmap: {result['heatmap']['path']}")
    if "sweep" in result:
        first = result['sweep']['rows'][0]
        where = ("" if first.get("on") != "sheet" else
                 f" for the layout's sheet, as build builds it, errors over its {first['weights']} weight vectors")
        print(f"\nepsilon sweep (hybrid rebuilt per epsilon{where}; corrected area at weights "
              f"{[round(x, 4) for x in first['test_weights']]})")
        rows = [[f"{r['epsilon_mm']:g}", f"{r['max_error_mm']:.2f}", f"{r['mean_error_mm']:.3f}", r["references"],
                 r["depth"], f"{r['correction_mb']:.3f}", f"{r['correction_percent']:.1f}",
                 f"{r['corrected_area_percent']:.1f}"] for r in result["sweep"]["rows"]]
        print(_table(["epsilon mm", "max mm", "mean mm", "refs", "depth", "MB", "% sources", "area %"], rows))
        rows = [[u["depth"], u["references"], f"{u['max_error_mm']:.2f}", f"{u['mean_error_mm']:.3f}",
                 f"{u['correction_bytes'] / 1e6:.3f}"] for u in result["sweep"]["uniform"]]
        print("uniform subdivision (every cell split to a depth, nothing dropped)")
        print(_table(["depth", "refs", "max mm", "mean mm", "MB"], rows))
        print(f"sweep figure: {result['sweep']['path']}")
    if "ground_truth" in result:
        gt = result["ground_truth"]
        print("\nground truth: blends vs the generator's motion at the blended parameters, all phases")
        print("sources reproduced by their true motion (a check, ~0): " + ", ".join(
            f"{s['name']} max {s['max_mm']:.3f} mm" for s in gt["sources"]))
        worst = max(s["max_mm"] for s in gt["sources"])
        if worst > 1.0:
            print(f"warning: the true motion misses the sources by up to {worst:.1f} mm, so the errors below "
                  "include that difference (docs/evaluation.md, 'Ground truth')")
        methods = [m for m in ("linear", "hybrid", "nonlinear") if m in gt["summary"]]
        rows = []
        labelled = [(", ".join(f"{w:.2f}" for w in r["weights"]), r) for r in gt["rows"]] + [("mean", gt["summary"])]
        for label, r in labelled:
            speed = f"{r['params']['speed']:.2f}" if "params" in r else ""
            for m in methods:
                e = r[m]
                rows.append([label if m == methods[0] else "", speed if m == methods[0] else "", m,
                             f"{e['mean_mm']:.2f}", f"{e['max_mm']:.1f}", f"{e['edge_error_percent']:.2f}",
                             f"{e['volume_error_percent']:.2f}"])
            if "ratio_mean" in r:
                rows.append(["", "", "linear/nonlinear", f"{r['ratio_mean']:.2f}", f"{r['ratio_max']:.2f}",
                             f"{r['ratio_edge']:.2f}", f"{r['ratio_volume']:.2f}"])
        print(_table(["weights", "m/s", "method", "mean mm", "max mm", "edge %", "volume %"], rows))


def _write_png(path, image):
    from PIL import Image

    Image.fromarray(image).save(path, format="PNG")


def heatmap_weights(weights):
    """--weights normalised to sum 1 (finite, >= 0, not all 0; divided by their largest first, so huge ones
    do not overflow the sum); a ValueError naming the option otherwise."""
    w = np.asarray(weights, dtype=np.float64)
    if not (np.all(np.isfinite(w)) and np.all(w >= 0) and w.max() > 0):
        raise ValueError(f"--weights must be finite, non-negative and not all zero, got {' '.join(map(str, weights))}")
    w = w / w.max()
    return w / w.sum()


def run(args):
    if args.space.is_dir():
        raise ValueError(f"{args.space}: is a directory, not a motion space file")
    if not args.space.is_file():
        raise FileNotFoundError(f"{args.space}: no such motion space file")
    if not 1 <= args.timing_calls <= MAX_TIMING_CALLS:
        raise ValueError(f"--timing-calls must be between 1 and {MAX_TIMING_CALLS}, got {args.timing_calls}")
    if args.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
    if not all(math.isfinite(e) and e > 0 for e in args.epsilons_mm):
        raise ValueError(f"--epsilons-mm must be positive numbers of millimetres, got "
                         f"{' '.join(f'{e:g}' for e in args.epsilons_mm)}")
    if args.phase is not None and not 0.0 <= args.phase <= 1.0:
        raise ValueError(f"--phase must be in [0, 1], got {args.phase:g}")
    weights = heatmap_weights(args.weights) if args.weights is not None else None
    out = args.out or args.space.with_name(f"{args.space.stem}-eval")
    check_output_path(out, "--out", directory=True)
    made = next((p for p in [out.absolute(), *out.absolute().parents] if not p.exists()
                 and p.parent.exists()), None)  # the directory to remove if nothing is written
    space = MotionSpace.open(args.space)
    progress = StageBars(leave=False)
    result = {"space": str(args.space)}
    staged = []   # (temporary, final) pictures: put in place with results.json when the run has finished
    try:
        if weights is not None and len(weights) != space.n_sources:
            raise ValueError(f"--weights: expected {space.n_sources} weights ({', '.join(space.source_names)}) for "
                             f"{args.space}, got {len(weights)}")
        truth = capture_truth(space, args.captures) if args.captures is not None else None
        out.mkdir(parents=True, exist_ok=True)
        cache = evaluation.BlendCache(space, progress)
        errors = evaluation.blend_errors(space, cache=cache, timing_calls=args.timing_calls,
                                         nonlinear_timing_calls=max(1, args.timing_calls // 5), seed=args.seed,
                                         progress=progress)
        result["errors"] = errors
        worst = errors["methods"]["hybrid_1"]
        weights = weights if weights is not None else worst["worst_weights"]
        phase = args.phase if args.phase is not None else worst["worst_phase"]
        path = out / "heatmap.png"
        staged.append((out / ".heatmap.png.part", path))
        _write_png(staged[-1][0], evaluation.heatmap_figure(space, weights, phase, cache=cache))
        poses = evaluation.pose_errors(space, weights, phase, cache=cache)
        result["heatmap"] = {"path": str(path), "weights": list(map(float, weights)), "phase": float(phase),
                             "max_error_mm": {m: 1000.0 * float(e.max()) for m, (_, e) in poses.items()}}
        if args.sweep:
            rows = evaluation.epsilon_sweep(space, args.epsilons_mm, cache=cache, progress=progress)
            uniform = evaluation.uniform_subdivision(space, cache=cache)
            path = out / "epsilon_sweep.png"
            staged.append((out / ".epsilon_sweep.png.part", path))
            _write_png(staged[-1][0], evaluation.sweep_figure(rows, uniform=uniform, title=f"{space.name}: hybrid blending "
                                                     "against its error threshold epsilon"))
            result["sweep"] = {"path": str(path), "rows": rows, "uniform": uniform}
        if truth is not None:
            body, true_motion, sources = truth
            gt = evaluation.ground_truth_comparison(space, body, true_motion, cache=cache, progress=progress)
            for s, info in zip(gt["sources"], sources):
                s.update(info)
            result["ground_truth"] = gt
        result["results"] = str(out / "results.json")
        (out / ".results.json.part").write_text(json.dumps(result, indent=1, default=_json_default))
        staged.append((out / ".results.json.part", out / "results.json"))
        for part, final in staged:   # the run's files replace an earlier run's only once all are written
            part.replace(final)
        if not args.sweep:  # an earlier run's sweep picture does not stay beside results without a sweep
            (out / "epsilon_sweep.png").unlink(missing_ok=True)
        staged = []
    except BaseException:
        if made is not None:  # an --out made for this run: nothing left behind
            shutil.rmtree(made, ignore_errors=True)
        else:   # an --out of the user's: an earlier run's files stay as they were
            for part, _ in staged:
                part.unlink(missing_ok=True)
        raise
    finally:
        progress.close()
        space.close()
    if args.json:
        print(json.dumps(result, default=_json_default))
    else:
        _print_report(result)
        print(f"results: {result['results']}")
    return 0


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")

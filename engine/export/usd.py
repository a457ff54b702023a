"""A played clip as USD (usd-core's ``pxr``): time-sampled points under a time-sampled root transform.

Layout of the stage (``upAxis`` Y, ``metersPerUnit`` 1, ``timeCodesPerSecond`` and
``framesPerSecond`` the clip's rate, time codes 0 .. frames - 1, so time code k is frame k; a
recorded stream's frames, not 1 / rate apart, are at time code time x rate)::

    /<space>            Xform (a graph performance: the graph's name), the default prim, kind component
        xformOp:translate    root position (m), one sample per frame
        xformOp:rotateY      heading (degrees about +Y), one sample per frame
        /<space>/mesh   Mesh: faces once; points (root-local, float32) and extent per frame

Points are float32 as the player makes them (exact); the root transform is double translate
and float rotate, so world positions agree with the player's to float32 rounding.
``.usdc`` (binary crate, the default) or ``.usda`` (text) follows the file name.
"""

from __future__ import annotations

import math
import os
import re
import secrets
from pathlib import Path

import numpy as np


def _prim_name(name):
    """A valid USD prim name from a space name (letters, digits, underscores; not a leading digit)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", name) or "clip"
    return name if not name[0].isdigit() else f"_{name}"


def write_usd(path, frames, progress=None):
    """Write the clip ``frames`` (engine.export.clip.ClipFrames) to ``path`` (.usd, .usdc or .usda).

    ``progress(done, total)`` is called as frames are written. Returns ``{"frames", "prim"}``.
    """
    try:
        from pxr import Tf, Usd  # usd-core: imported only when exporting USD
    except ImportError:
        raise ValueError("USD export needs usd-core (pip install usd-core; scripts/setup-env installs it)") from None

    path = Path(path)
    if path.suffix not in (".usd", ".usdc", ".usda"):
        raise ValueError(f"{path}: a USD file name must end in .usd, .usdc or .usda")
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.{secrets.token_hex(6)}{path.suffix}")  # renamed when complete
    try:
        try:
            stage = Usd.Stage.CreateNew(str(temporary))
            prim = _fill(stage, frames, progress)
            if not stage.GetRootLayer().Save():
                raise OSError(f"cannot write {path}: USD could not save the stage")
        except Tf.ErrorException as exc:  # USD's own errors (a directory it cannot write, a full disk)
            text = " ".join(str(exc).split())  # "Error in '<function>' at line N in file F : '<reason>'"
            reason = text.rsplit(" : ", 1)[-1].strip("'\" ")
            raise OSError(f"cannot write {path}: {reason.replace(str(temporary), str(path))}") from None
        del stage
        os.replace(temporary, path)
    finally:
        if temporary.exists():
            temporary.unlink()
    return {"frames": len(frames), "prim": prim}


def _fill(stage, frames, progress):
    from pxr import Gf, Kind, Usd, UsdGeom, Vt

    n_frames = len(frames)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(frames.rate)
    stage.SetFramesPerSecond(frames.rate)
    stage.SetStartTimeCode(0)
    uniform = frames.uniform  # time code k is frame k; else (a stream's recording) time x rate
    codes = list(range(n_frames)) if uniform else (np.asarray(frames.times) * frames.rate).tolist()
    stage.SetEndTimeCode(codes[-1])
    prim_name = _prim_name(frames.space)
    root = UsdGeom.Xform.Define(stage, f"/{prim_name}")
    stage.SetDefaultPrim(root.GetPrim())
    Usd.ModelAPI(root.GetPrim()).SetKind(Kind.Tokens.component)
    custom = {"space": frames.space, "rate": frames.rate, "parameters": list(frames.names)}
    if frames.nodes is not None:
        custom["graph"] = frames.space
    root.GetPrim().SetCustomDataByKey("morphspace", custom)
    translate = root.AddTranslateOp()
    rotate = root.AddRotateYOp()
    mesh = UsdGeom.Mesh.Define(stage, f"/{prim_name}/mesh")
    F = np.asarray(frames.faces, dtype=np.int32)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(F.reshape(-1)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    points, extent = mesh.CreatePointsAttr(), mesh.CreateExtentAttr()
    lo, hi = frames.local.min(axis=1), frames.local.max(axis=1)
    for k in range(n_frames):
        time = Usd.TimeCode(codes[k])
        points.Set(Vt.Vec3fArray.FromNumpy(frames.local[k]), time)
        extent.Set(Vt.Vec3fArray([Gf.Vec3f(*lo[k].tolist()), Gf.Vec3f(*hi[k].tolist())]), time)
        translate.Set(Gf.Vec3d(*frames.root_position[k].tolist()), time)
        rotate.Set(float(math.degrees(frames.heading[k])), time)
        if progress is not None and (k % 16 == 15 or k == n_frames - 1):
            progress(k + 1, n_frames)
    return f"/{prim_name}"

"""USD exports: usd-core's validators (what usdchecker runs) find no error; the stage read back
with pxr places the time-sampled points where the player put them."""

import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core is in the test extras: scripts/setup-env test")
from pxr import Usd, UsdGeom  # noqa: E402

from engine.export import Clip, play_clip, write_export  # noqa: E402

_spec = importlib.util.spec_from_file_location(
    "validate_usd", Path(__file__).resolve().parents[1] / "validators" / "validate_usd.py")
_validate_usd = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_validate_usd)


def validation_errors(stage):
    """Errors of every registered UsdValidation validator except the usdz packaging ones (the
    checker documented in docs/exports.md: tests/validators/validate_usd.py)."""
    return _validate_usd.validation_errors(stage)


def test_the_documented_checker_fails_a_bad_file_and_passes_an_export(turning, tmp_path):
    """``validate_usd.py FILE`` as docs/exports.md runs it: exit 1 on an empty stage, 0 on an export."""
    empty = tmp_path / "empty.usda"
    Usd.Stage.CreateNew(str(empty)).Save()
    good = tmp_path / "clip.usda"
    write_export(good, turning, "usd")
    script = Path(__file__).resolve().parents[1] / "validators" / "validate_usd.py"
    bad = subprocess.run([sys.executable, str(script), str(empty)], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1 and "errors" in bad.stdout and "metersPerUnit" in bad.stdout
    ok = subprocess.run([sys.executable, str(script), str(good)], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and ok.stdout.strip() == f"{good}: no errors"
    missing = subprocess.run([sys.executable, str(script), str(tmp_path / "none.usd")], capture_output=True, text=True,
                             timeout=120)
    assert missing.returncode == 1 and missing.stderr == "", missing.stderr   # not a traceback
    assert missing.stdout.startswith(f"{tmp_path / 'none.usd'}: cannot open it (")


@pytest.fixture(scope="module")
def turning(export_spaces):
    return play_clip(export_spaces["speed"], Clip(params={"speed": 2.0}, duration=2.0, rate=24,
                                                  track=((0.5, {"speed": 1.0}),)))


def test_an_empty_stage_has_errors():
    """The check can fail: a stage without up axis, units and default prim is reported."""
    errors = validation_errors(Usd.Stage.CreateInMemory())
    assert any("upAxis" in e for e in errors) and any("metersPerUnit" in e for e in errors)


@pytest.mark.parametrize("name", ["clip.usd", "clip.usda"])
def test_validators_find_no_error_and_frames_come_back(turning, tmp_path, name):
    stats = write_export(tmp_path / name, turning, "usd")
    assert stats["frames"] == len(turning) and stats["prim"] == "/speed"
    assert [p.name for p in tmp_path.iterdir()] == [name]  # the temporary file was renamed
    stage = Usd.Stage.Open(str(tmp_path / name))
    assert validation_errors(stage) == []
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == 24 and stage.GetFramesPerSecond() == 24
    assert stage.GetStartTimeCode() == 0 and stage.GetEndTimeCode() == len(turning) - 1
    assert stage.GetDefaultPrim().GetPath() == "/speed"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/speed/mesh"))
    assert np.array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), turning.faces)
    assert mesh.GetPointsAttr().GetNumTimeSamples() == len(turning)
    cache = UsdGeom.XformCache()
    for k in range(len(turning)):
        time = Usd.TimeCode(k)
        points = np.array(mesh.GetPointsAttr().Get(time), dtype=np.float64)
        assert np.array_equal(points, turning.local[k])  # float32 points: exact
        cache.SetTime(time)
        M = np.array(cache.GetLocalToWorldTransform(mesh.GetPrim()))  # row vectors: p' = p M
        placed = points @ M[:3, :3] + M[3, :3]
        np.testing.assert_allclose(placed, turning.world(k), rtol=0, atol=2e-6, err_msg=str(k))
        extent = np.array(mesh.GetExtentAttr().Get(time))
        assert np.allclose(extent, [turning.local[k].min(axis=0), turning.local[k].max(axis=0)])
    assert math.isclose(UsdGeom.Xformable(stage.GetPrimAtPath("/speed")).GetOrderedXformOps()[1]
                        .Get(Usd.TimeCode(len(turning) - 1)), math.degrees(turning.heading[-1]), abs_tol=1e-4)


def test_a_usd_name_is_required(turning, tmp_path):
    with pytest.raises(ValueError, match="must end in .usd, .usdc or .usda"):
        write_export(tmp_path / "clip.usdz", turning, "usd")
    assert list(tmp_path.iterdir()) == []

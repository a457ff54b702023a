"""USD exports: usd-core's validators (what usdchecker runs) find no error; the stage read back
with pxr places the time-sampled points where the player put them."""

import math

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core is in the test extras: scripts/setup-env test")
from pxr import Usd, UsdGeom, UsdValidation  # noqa: E402

from engine.export import Clip, play_clip, write_export  # noqa: E402


def validation_errors(stage):
    """Errors of every registered UsdValidation validator except the usdz packaging ones (usd-core
    26 has no Python ComplianceChecker and its wheel no usdchecker program)."""
    registry = UsdValidation.ValidationRegistry()
    validators = [registry.GetOrLoadValidatorByName(m.name) for m in registry.GetAllValidatorMetadata()
                  if "UsdzValidators" not in m.GetKeywords()]
    assert len(validators) > 10
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    return [e.GetErrorAsString() for e in errors if e.GetType() != UsdValidation.ValidationErrorType.Info]


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

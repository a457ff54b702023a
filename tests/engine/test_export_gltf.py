"""Binary glTF exports: the Khronos glTF Validator finds no issue, and the file read back by an
independent reader (gltf_reader.py) plays the player's frames within the format's precision."""

import json
from dataclasses import replace

import numpy as np
import pytest

from engine.export import Clip, play_clip, write_export
from engine.export.gltf import glb_bytes
from gltf_reader import Glb, animated_frames
from gltf_validator import assert_clean, validate

@pytest.fixture(scope="module")
def steered(export_spaces):
    """4 s at 30 frames/s of the speed space, sped up at 1 s and slowed at 2.5 s."""
    return play_clip(export_spaces["speed"], Clip(params={"speed": 1.0}, duration=4.0, rate=30,
                                                  track=((1.0, {"speed": 2.5}), (2.5, {"speed": 1.4}))))


def world(frames):
    return np.stack([frames.world(k) for k in range(len(frames))]).astype(np.float64)


@pytest.mark.parametrize("precision, interpolation", [("int16", "LINEAR"), ("float32", "STEP")])
def test_validator_finds_no_issue_and_frames_come_back(steered, tmp_path, precision, interpolation):
    path = tmp_path / "clip.glb"
    stats = write_export(path, steered, "glb", precision=precision, interpolation=interpolation)
    report = validate(path)
    assert_clean(report)
    assert report["issues"]["numInfos"] == 0 and report["info"]["animationCount"] == 1
    times, vertices, faces, shown = animated_frames(path.read_bytes())
    np.testing.assert_allclose(times, steered.times, rtol=0, atol=1e-6)
    assert np.array_equal(faces, steered.faces) and np.array_equal(shown, np.arange(len(steered)))
    error = np.abs(vertices - world(steered)).max()
    bound = stats["max_error_m"] + 2e-6  # the format's rounding + float32 placement
    assert error <= bound, (error, bound)
    if precision == "int16":
        assert 1e-6 < stats["max_error_m"] < 2e-5  # a 1.8 m body on a 16-bit grid
        assert Glb(path.read_bytes()).json["extensionsRequired"] == ["KHR_mesh_quantization"]
    else:
        assert stats["max_error_m"] == 0 and error < 2e-6
    doc = Glb(path.read_bytes()).json
    assert {s["interpolation"] for s in doc["animations"][0]["samplers"]} == {interpolation, "LINEAR"}


def test_the_projects_glb_reader_sees_the_first_frame(steered, tmp_path):
    """engine.mesh_io (trimesh, which ignores accessors' 'normalized' flag) reads the base mesh
    placed by the nodes: the first frame, to the 16-bit step."""
    from engine.mesh_io import read_mesh

    stats = write_export(tmp_path / "clip.glb", steered, "glb")
    mesh = read_mesh(tmp_path / "clip.glb")
    assert np.array_equal(mesh.faces, steered.faces)
    assert np.abs(mesh.vertices - steered.world(0)).max() <= stats["max_error_m"] + 2e-6


def test_the_int16_file_is_two_thirds_of_the_float32_one(steered):
    small, _ = glb_bytes(steered, precision="int16")
    large, _ = glb_bytes(steered, precision="float32")
    n = steered.local.shape[1] * len(steered)  # base and targets: 12 -> 8 bytes per vertex and frame
    assert len(large) - len(small) == pytest.approx(4 * n, rel=0.03)  # (+ longer float bounds in the JSON)


def test_held_frames_share_a_target(export_spaces, tmp_path):
    frames = play_clip(export_spaces["jump"], Clip(duration=3.0, rate=15))  # the jump ends before 3 s
    path = tmp_path / "jump.glb"
    stats = write_export(path, frames, "glb")
    assert_clean(validate(path))
    assert stats["targets"] < len(frames) and stats["empty_targets"] == 1
    _, vertices, _, shown = animated_frames(path.read_bytes())
    assert shown[-1] == shown[-2] == stats["targets"] - 1
    assert np.abs(vertices - world(frames)).max() <= stats["max_error_m"] + 2e-6


@pytest.mark.parametrize("precision", ["int16", "float32"])
def test_targets_where_few_vertices_move_are_sparse(steered, tmp_path, precision):
    """A clip where only a hand's worth of vertices move: those targets are stored sparse (indices
    and values), which the validator accepts and the reader expands back."""
    local = np.repeat(steered.local[:1], 12, axis=0)
    moving = np.arange(0, local.shape[1], 50)
    local[:, moving, 1] += np.linspace(0, 0.2, 12, dtype=np.float32)[:, None]
    local[6:] = local[5]  # frames 6.. equal to frame 5: one shared target
    frames = replace(steered, times=steered.times[:12], local=local, root_position=steered.root_position[:12],
                     heading=steered.heading[:12], params=steered.params[:12])
    path = tmp_path / "sparse.glb"
    stats = write_export(path, frames, "glb", precision=precision)
    assert_clean(validate(path))
    assert stats["sparse_targets"] == 5 and stats["dense_targets"] == 0 and stats["empty_targets"] == 1
    row = (6 if precision == "int16" else 12) + 2  # values + uint16 index
    assert stats["target_bytes"] == 5 * len(moving) * row + 5 * (-len(moving) * row % 4)  # padding to 4 bytes
    _, vertices, _, _ = animated_frames(path.read_bytes())
    assert np.abs(vertices - world(frames)).max() <= stats["max_error_m"] + 2e-6


def test_the_validator_catches_a_broken_file(steered, tmp_path):
    """The check can fail: a file whose accessor bounds lie is reported with errors."""
    data, _ = glb_bytes(steered, precision="float32")
    glb = Glb(data)
    document = glb.json
    document["accessors"][0]["max"] = [9.0, 9.0, 9.0]
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    import struct

    binary = glb.bin
    blob = struct.pack("<III", 0x46546C67, 2, 28 + len(text) + len(binary)) + struct.pack("<II", len(text),
                                                                                           0x4E4F534A)
    blob += text + struct.pack("<II", len(binary), 0x004E4942) + binary
    (tmp_path / "broken.glb").write_bytes(blob)
    report = validate(tmp_path / "broken.glb")
    assert report["issues"]["numErrors"] > 0
    assert any(m["code"] == "ACCESSOR_MAX_MISMATCH" for m in report["issues"]["messages"])


def test_bad_options_are_clear_errors(steered):
    with pytest.raises(ValueError, match="precision must be one of int16, float32"):
        glb_bytes(steered, precision="half")
    with pytest.raises(ValueError, match="interpolation must be one of LINEAR, STEP"):
        glb_bytes(steered, interpolation="CUBICSPLINE")

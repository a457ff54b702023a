"""Bad input to `morphspace build`: a one-line error naming the option, file or spec key and the
problem, exit status 2, no traceback, nothing written, and before any work (found by a bad-input
trial). The sources here are empty directories: every check runs before a mesh is read."""

import json

import numpy as np

import pytest
from cli_refused import refused

from server.commands.build import read_spec

SPEC = """
name = "s"
captures = "{captures}"
sources = ["walk", "jog"]

[parameters]
layout = "chain"
chain = ["walk", "jog"]
measures = ["speed"]
resolution = 5
"""


def _refused(capsys, argv, *expected):
    return refused(capsys, ["build", *argv], *expected)


def _nothing_written(directory):
    assert not list(directory.glob("*.mspace")) and not list(directory.glob(".*.tmp"))


@pytest.fixture
def sources(tmp_path):
    """Two --source directories (empty: nothing gets as far as reading them)."""
    argv = []
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        argv += ["--source", tmp_path / name]
    return argv


@pytest.fixture
def captures(tmp_path):
    """A capture dataset with empty sequences walk and jog, for specs."""
    for name in ("walk", "jog"):
        (tmp_path / "captures" / "sequences" / name).mkdir(parents=True)
    (tmp_path / "captures" / "manifest.json").write_text("{}")
    return tmp_path / "captures"


@pytest.mark.parametrize("option,value,message", [
    ("--fps", "0", "--fps must be a number above 0 and at most 1000 frames/s, got 0.0"),
    ("--fps", "inf", "--fps must be a number above 0 and at most 1000 frames/s, got inf"),
    ("--fps", "nan", "--fps must be a number above 0 and at most 1000 frames/s, got nan"),
    ("--fps", "-5", "--fps must be a number above 0 and at most 1000 frames/s, got -5.0"),
    ("--phases", "100000", "--phases must be an integer from 2 to 512, got 100000"),
    ("--phases", "0", "--phases must be an integer from 2 to 512, got 0"),
    ("--phases", "1", "--phases must be an integer from 2 to 512, got 1"),
    ("--epsilon-mm", "nan", "--epsilon-mm must be a number above 0 and at most 100 (mm), got nan"),
    ("--epsilon-mm", "inf", "--epsilon-mm must be a number above 0 and at most 100 (mm), got inf"),
    ("--epsilon-mm", "0", "--epsilon-mm must be a number above 0 and at most 100 (mm), got 0.0"),
])
def test_bad_options_are_refused_before_any_work(tmp_path, capsys, sources, option, value, message):
    _refused(capsys, [*sources, "--out", tmp_path / "o.mspace", option, value], message)
    _nothing_written(tmp_path)


@pytest.mark.parametrize("meta,message", [
    ('{"name": "a", "fps": 0, "cyclic": false}', "meta.json: fps must be a number above 0 and at most 1000"),
    ('{"name": "a", "fps": Infinity, "cyclic": false}', "meta.json: fps must be a number above 0 and at most 1000"),
    ('{"name": "a", "fps": "fast", "cyclic": false}', "meta.json: fps must be a number above 0 and at most 1000 "
                                                      "frames/s, got 'fast'"),
    ('{"name": "a", "fps": 30, "cyclic": "yes"}', "meta.json: cyclic must be true or false, got 'yes'"),
    ("[1, 2]", "meta.json: not a JSON object"),
    ("{{{", "meta.json: not valid JSON"),
])
def test_a_bad_meta_json_is_named(tmp_path, capsys, sources, meta, message):
    for directory in (tmp_path / "a", tmp_path / "b"):
        (directory / "meta.json").write_text(meta)
        (directory / "consistent").mkdir()
    err = _refused(capsys, [*sources, "--out", tmp_path / "o.mspace"], message)
    assert str(tmp_path / "a" / "meta.json") in err
    _nothing_written(tmp_path)


def test_the_demo_like_spec_passes_the_checks(tmp_path, captures):
    (tmp_path / "s.toml").write_text(SPEC.format(captures=captures))
    spec = read_spec(tmp_path / "s.toml")
    assert spec["names"] == ["walk", "jog"] and spec["parameters"]["resolution"] == 5


@pytest.mark.parametrize("change,message", [
    (lambda s: s.replace('captures = "', 'captures = 7\n# "'), "captures must be a path (a non-empty string), got 7"),
    (lambda s: s.replace('name = "s"', 'name = "s"\nepsilon_mm = "five"'),
     "epsilon_mm must be a number above 0 and at most 100 (mm), got 'five'"),
    (lambda s: s.replace('name = "s"', 'name = "s"\nepsilon_mm = nan'), "epsilon_mm must be a number above 0"),
    (lambda s: s.replace('name = "s"', 'name = "s"\nphases = 1'), "phases must be an integer from 2 to 512, got 1"),
    (lambda s: s.replace('name = "s"', 'name = "s"\nphases = 100000'), "phases must be an integer from 2 to 512"),
    (lambda s: s.replace('name = "s"', 'name = 5'), "name must be a non-empty string"),
    (lambda s: s.replace('name = "s"', 'name = "../s"'), "name must be a non-empty string without '/'"),
    (lambda s: s.replace('name = "s"', 'name = "s"\nbogus_key = 1'), "unknown key(s) bogus_key; known: name,"),
    (lambda s: s.replace("resolution = 5", "resolution = 2.5"),
     "parameters.resolution must be an integer from 2 to 41, got 2.5"),
    (lambda s: s.replace("resolution = 5", "resolution = 100000000"), "parameters.resolution must be an integer"),
    (lambda s: s.replace("resolution = 5", "resolution = 0"), "parameters.resolution must be an integer"),
    (lambda s: s.replace("resolution = 5", "resolution = 1"), "parameters.resolution must be an integer"),
    (lambda s: s.replace("resolution = 5", "resolution = -5"), "parameters.resolution must be an integer"),
    (lambda s: s.replace("resolution = 5", "colour = 1"), "parameters: unknown key(s) colour"),
    (lambda s: s.replace('chain = ["walk", "jog"]', 'chain = "walk"'), "parameters.chain must be a list of"),
    (lambda s: s.replace('chain = ["walk", "jog"]', 'chain = ["walk", "walk"]'),
     "parameters: the chain layout names 'walk' twice"),
    (lambda s: s.replace('sources = ["walk", "jog"]', 'sources = ["walk", "walk", "jog"]'),
     "source 'walk' is listed twice"),
    (lambda s: s.replace('sources = ["walk", "jog"]', 'sources = [{name = "walk", pth = "x"}, "jog"]'),
     "source 'walk': unknown key(s) pth"),
    (lambda s: s.replace('measures = ["speed"]', 'measures = "speed"'), "parameters.measures must list 1 to 3"),
    (lambda s: s.replace('chain = ["walk", "jog"]', 'chain = ["walk", "jog"]\nleft = "walk"'),
     "parameters.left is not part of a chain layout (it takes chain)"),
    (lambda s: s.replace('chain = ["walk", "jog"]', 'chain = ["walk", "jog"]\ncorners = ["walk", "jog", "walk", "jog"]'),
     "parameters.corners is not part of a chain layout"),
    (lambda s: s.replace('sources = ["walk", "jog"]', 'sources = ["walk", "jog", {name = "run", path = "captures/sequences/jog"}]'),
     "parameters: the chain layout leaves out 'run': every source needs its place in the layout"),
    (lambda s: s.replace('chain = ["walk", "jog"]', 'chain = ["walk", "jag"]'),
     "parameters refer to 'jag', which is not among the sources"),
])
def test_bad_spec_keys_are_named(tmp_path, capsys, captures, change, message):
    (tmp_path / "s.toml").write_text(change(SPEC.format(captures=captures)))
    err = _refused(capsys, [tmp_path / "s.toml", "--out", tmp_path / "o.mspace"], message)
    assert f"{tmp_path / 's.toml'}: " in err
    _nothing_written(tmp_path)


def test_directories_as_the_spec_or_the_output_are_refused_before_any_work(tmp_path, capsys, sources, captures):
    (tmp_path / "empty").mkdir()
    _refused(capsys, [tmp_path / "empty"], f"{tmp_path / 'empty'} is a directory, not a spec file")
    _refused(capsys, [*sources, "--out", tmp_path / "empty", "--force"],
             f"--out {tmp_path / 'empty'} is a directory, not a file")
    (tmp_path / "s.toml").write_text(SPEC.format(captures=captures))
    (tmp_path / "s.mspace").mkdir()  # the spec's default output
    _refused(capsys, [tmp_path / "s.toml", "--force"], f"{tmp_path / 's.mspace'} is a directory, not a file")
    _refused(capsys, [tmp_path / "s.toml", "--out", tmp_path / "s.toml", "--force"], "is the input")
    _refused(capsys, [*sources, "--out", tmp_path / "s.toml" / "o.mspace"], "s.toml is a file, not a directory")
    assert list((tmp_path / "empty").iterdir()) == [] and not list(tmp_path.glob(".*.tmp"))
    assert (tmp_path / "s.toml").read_text() == SPEC.format(captures=captures)


def test_a_capture_dataset_as_a_source_says_to_use_its_sequences(tmp_path, capsys, sources, captures):
    _refused(capsys, ["--source", captures, *sources[2:], "--out", tmp_path / "o.mspace"],
             f"{captures} is a capture dataset, not a sequence: use its sequences/<name> (it has jog, walk)")
    _nothing_written(tmp_path)


def test_a_meta_json_without_name_fps_or_cyclic_takes_them_from_the_directory_and_options(tmp_path):
    from server.commands.build import load_source

    directory = tmp_path / "take"
    (directory / "consistent").mkdir(parents=True)
    (directory / "consistent" / "frame_0000.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (directory / "meta.json").write_text(json.dumps({"units": "m"}))
    clip, _ = load_source(directory, fps=24.0, cyclic=True)
    assert (clip.name, clip.fps, clip.cyclic) == ("take", 24.0, True)


def test_the_cli_and_the_rest_build_job_take_the_same_phases():
    """``--phases`` / the spec's ``phases`` and the REST job's ``phases``: one range, 2..512."""
    import pydantic
    from server.commands.build import PHASES
    from server.jobs.models import BuildSpec

    field = BuildSpec.model_fields["phases"]
    bounds = {name: getattr(m, name) for m in field.metadata for name in ("ge", "le") if hasattr(m, name)}
    assert (bounds["ge"], bounds["le"]) == PHASES == (2, 512)
    assert BuildSpec(sources=["a", "b"], phases=2).phases == 2
    for bad in (1, 513):
        with pytest.raises(pydantic.ValidationError):
            BuildSpec(sources=["a", "b"], phases=bad)


def test_a_source_of_one_frame_is_refused_by_name(capsys, tmp_path):
    """(a docs-only user got only the root motion's own message, naming no source)"""
    one = tmp_path / "one"
    one.mkdir()
    (one / "frame_0000.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    other = tmp_path / "other"
    other.mkdir()
    (other / "frame_0000.obj").write_text((one / "frame_0000.obj").read_text())
    (other / "frame_0001.obj").write_text((one / "frame_0000.obj").read_text())
    _refused(capsys, ["--source", one, "--source", other, "--out", tmp_path / "s.mspace"],
             f"{one}: 1 frame; a source needs at least 2")
    _nothing_written(tmp_path)


def test_the_same_source_twice_and_a_missing_rest_are_refused_before_any_work(tmp_path, capsys, sources, captures):
    a = sources[1]
    _refused(capsys, ["--source", a, "--source", tmp_path / "x" / ".." / "a", "--out", tmp_path / "o.mspace"],
             f"--source {tmp_path / 'x' / '..' / 'a'}: given twice (also as {a}); sources must be different")
    _refused(capsys, [*sources, "--out", tmp_path / "o.mspace", "--rest", tmp_path / "nope.obj"],
             f"--rest {tmp_path / 'nope.obj'}: not a file")
    (tmp_path / "s.toml").write_text(SPEC.format(captures=captures).replace('name = "s"', 'name = "s"\nrest = "nope.obj"'))
    _refused(capsys, [tmp_path / "s.toml", "--out", tmp_path / "o.mspace"],
             f"{tmp_path / 's.toml'}: rest: {captures / 'nope.obj'} is not a file")
    _nothing_written(tmp_path)


def test_sources_that_mix_cyclic_and_one_shot_are_named():
    from engine.motion_space import SourceClip, build_motion_space

    V = np.zeros((3, 4, 3))
    clips = [SourceClip("walk", V, 30.0, True), SourceClip("jump", V, 30.0, False), SourceClip("jog", V, 30.0, True)]
    with pytest.raises(ValueError, match=r"walk, jog cyclic, jump not \(meta.json's cyclic"):
        build_motion_space("/nonexistent/x.mspace", clips, np.array([[0, 1, 2], [0, 2, 3]]), name="x")

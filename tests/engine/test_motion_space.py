"""Building, writing and opening motion spaces."""

import numpy as np
import pytest

from engine.motion_space import MotionSpace, MotionSpaceError, SourceClip, build_motion_space, resample_clip
from engine.synthetic import animate, build_body, gait, jump


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


@pytest.fixture(scope="module")
def space_path(body, tmp_path_factory):
    clips = []
    for name, speed in (("slow", 0.9), ("fast", 2.6)):
        motion = gait(body.skeleton, speed, cycles=1.5, start_phase=0.0, fps=15)
        clips.append(SourceClip(name, animate(body, motion), motion.fps, True, motion.frames_per_cycle, 0))
    path = tmp_path_factory.mktemp("spaces") / "gait.mspace"
    build_motion_space(path, clips, body.F, name="gait", n_phases=10, epsilon=0.006, rest=body.V)
    return path


def test_cycle_resampling_removes_drift_and_loops(body):
    motion = gait(body.skeleton, 1.4, cycles=2.0, start_phase=0.0)
    V = animate(body, motion)
    clip = SourceClip("walk", V, motion.fps, True, motion.frames_per_cycle, 0)
    N = motion.frames_per_cycle
    samples, velocity = resample_clip(clip, N)
    np.testing.assert_allclose(samples[0], V[0], atol=1e-12)  # phase 0 is the cycle's first frame
    assert velocity[2] == pytest.approx(1.4, rel=0.01) and abs(velocity[0]) < 1e-6
    # In the root frame the cycle closes: the frame after the last sample is the first again.
    local_next = V[N] - velocity * N / motion.fps
    np.testing.assert_allclose(local_next, samples[0], atol=1e-9)


def test_clip_too_short_for_its_cycle_is_refused(body):
    V = np.zeros((10, len(body.V), 3))
    with pytest.raises(ValueError, match="needs 25 frames"):
        resample_clip(SourceClip("x", V, 30.0, True, frames_per_cycle=20, cycle_start=5), 8)


def test_space_round_trip_matches_the_sources(space_path):
    with MotionSpace.open(space_path) as space:
        assert (space.n_sources, space.n_phases, space.cyclic) == (2, 10, True)
        assert space.source_names == ["slow", "fast"]
        assert not space.sources.flags.writeable  # memory-mapped, read-only
        for mode in ("linear", "hybrid", "nonlinear"):
            V = space.blend([1.0, 0.0], 0.3, mode)
            np.testing.assert_allclose(V, space.sources[3, 0], atol=2e-4 * space.model_size)
        # The epsilon bound holds on the phase grid (between samples the non-linear blend also
        # interpolates rotations in phase, the hybrid linearly).
        hybrid = space.blend([0.5, 0.5], 0.4, "hybrid")
        exact = space.blend([0.5, 0.5], 0.4, "nonlinear")
        assert np.linalg.norm(hybrid - exact, axis=1).max() <= space.metadata["epsilon"] * 1.05
        durations = space.durations()
        assert durations[0] > durations[1]  # the slow gait has the longer cycle


@pytest.mark.parametrize("weights,phase,match", [
    ([1.0], 0.1, "expected 2 weights"), ([np.nan, 1.0], 0.1, "finite"), ([-1.0, 2.0], 0.1, "non-negative"),
    ([0.0, 0.0], 0.1, "not all zero"), ([0.5, 0.5], np.inf, "phase must be finite")])
def test_bad_blend_requests_are_clear_errors(space_path, weights, phase, match):
    with MotionSpace.open(space_path) as space:
        with pytest.raises(ValueError, match=match):
            space.blend(weights, phase)
        with pytest.raises(ValueError, match="unknown blend mode"):
            space.blender("cubic")


def test_truncated_space_file_is_a_clear_error(space_path, tmp_path):
    data = space_path.read_bytes()
    broken = tmp_path / "broken.mspace"
    broken.write_bytes(data[: len(data) // 2])
    with pytest.raises(MotionSpaceError, match="truncated") as error:
        MotionSpace.open(broken)
    assert str(broken) in str(error.value)


def test_sources_must_agree(body, tmp_path):
    motion = jump(body.skeleton, 0.3, 0.5, fps=15)
    V = animate(body, motion)
    walk = gait(body.skeleton, 1.0, cycles=1.2, fps=15)
    cyclic = SourceClip("walk", animate(body, walk), 15.0, True, walk.frames_per_cycle, 0)
    one_shot = SourceClip("jump", V, 15.0, False)
    with pytest.raises(ValueError, match="all cyclic or all non-cyclic"):
        build_motion_space(tmp_path / "x.mspace", [cyclic, one_shot], body.F, name="x")
    with pytest.raises(ValueError, match="at least 2 sources"):
        build_motion_space(tmp_path / "x.mspace", [one_shot], body.F, name="x")
    other = SourceClip("other", V[:, :500], 15.0, False)
    with pytest.raises(ValueError, match="other: vertices have shape"):
        build_motion_space(tmp_path / "x.mspace", [one_shot, other], body.F, name="x")
    assert not (tmp_path / "x.mspace").exists()

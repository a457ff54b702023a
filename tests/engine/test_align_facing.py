"""Which way a body faces: it turns with the body, whichever way it stands."""

import numpy as np
import pytest

from engine.align import body_facing, body_frame
from engine.align.facing import FEET_CLEAR, _feet_reach
from engine.rotations import rot_y
from engine.synthetic import SequenceSpec, build_body, generate_sequence_data


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


@pytest.fixture(scope="module")
def walk_frames(body):
    """Unstructured (re-meshed, noisy) frames of a walk towards +Z."""
    data = generate_sequence_data(body, SequenceSpec("walk", "gait", {"speed": 1.2, "cycles": 0.5}), fps=10,
                                  seed=3)
    return [V for V, _, _ in data["unstructured"]]


def test_the_rest_body_faces_plus_z_with_its_left_at_plus_x(body):
    facing, left = body_frame(body.V)
    assert facing[1] == 0 and np.isclose(np.linalg.norm(facing), 1.0)
    assert np.degrees(np.arccos(facing @ [0, 0, 1])) < 3.0
    np.testing.assert_allclose(left, [facing[2], 0, -facing[0]])
    assert left[0] > 0.99


@pytest.mark.parametrize("degrees", [0, 90, 180, -135, 37])
def test_facing_turns_with_the_body(walk_frames, degrees):
    R = rot_y(np.radians(degrees))
    decided = 0
    for V in walk_frames:
        facing = body_facing(V)
        turned = body_facing(V @ R.T, fallback=R @ [0.0, 0.0, 1.0])
        np.testing.assert_allclose(turned, R @ facing, atol=1e-9)
        reach, height = _feet_reach(V)
        if np.linalg.norm(reach) >= FEET_CLEAR * height:  # the feet decide: the walk heads to +Z
            decided += 1
            assert np.degrees(np.arccos(np.clip(facing @ [0, 0, 1], -1, 1))) < 10.0
        else:  # the body's depth axis, on the fallback's side
            assert facing @ [0, 0, 1] > 0
    assert decided >= len(walk_frames) - 2


def test_without_feet_the_fallback_picks_the_side():
    rng = np.random.default_rng(0)
    box = rng.uniform([-0.25, 0.0, -0.1], [0.25, 1.7, 0.1], size=(2000, 3))  # wide, deep-less, no feet
    np.testing.assert_allclose(body_facing(box), [0, 0, 1], atol=0.05)
    np.testing.assert_allclose(body_facing(box, fallback=(0.3, 0, -1)), [0, 0, -1], atol=0.05)
    with pytest.raises(ValueError, match="shape"):
        body_facing(np.zeros((2, 3)))

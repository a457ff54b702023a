"""Phase tables give back the wrapped blender's frames exactly (to float32 rounding)."""

import numpy as np
import pytest

from engine.blend import LinearBlender
from engine.blend.cache import PhaseTableBlender


@pytest.mark.parametrize("cyclic", [True, False])
def test_tables_reproduce_the_blender_at_any_phase(cyclic):
    rng = np.random.default_rng(3)
    sources = rng.normal(size=(12, 3, 200, 3)).astype(np.float32)
    inner = LinearBlender(sources, cyclic)
    blender = PhaseTableBlender(inner, 12, cyclic, capacity=2, after=2)
    w = np.array([0.2, 0.5, 0.3])
    for phase in [0.0, 0.04, 0.5, 0.99, 1.0, *rng.random(20)]:
        np.testing.assert_allclose(blender.blend(w, phase), inner.blend(w, phase), atol=2e-6)
    assert blender.builds == 1 and blender.misses == 1
    out = np.empty((200, 3), np.float32)
    assert blender.blend(w, 0.3, out=out) is out


def test_tables_are_kept_least_recently_used():
    rng = np.random.default_rng(4)
    inner = LinearBlender(rng.normal(size=(8, 2, 50, 3)).astype(np.float32), True)
    blender = PhaseTableBlender(inner, 8, True, capacity=2, after=1)
    for w in ([1, 0], [0, 1], [0.5, 0.5], [1, 0]):
        blender.blend(np.array(w, float), 0.3)
    assert blender.builds == 4          # [1, 0] was evicted by the third and built again
    assert len(blender._tables) == 2

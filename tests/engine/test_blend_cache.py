"""Phase tables give back the wrapped blender's frames exactly (to float32 rounding)."""

import numpy as np
import pytest

from engine.blend import LinearBlender
from engine.blend.cache import PhaseTable, PhaseTableBlender


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


def test_idle_tables_are_replaced_least_recently_used():
    rng = np.random.default_rng(4)
    inner = LinearBlender(rng.normal(size=(8, 2, 50, 3)).astype(np.float32), True)
    blender = PhaseTableBlender(inner, 8, True, capacity=2, after=1, idle=0.0)
    for w in ([1, 0], [0, 1], [0.5, 0.5], [1, 0]):
        blender.blend(np.array(w, float), 0.3)
    assert blender.builds == 4          # [1, 0] was evicted by the third and built again
    assert len(blender._tables) == 2


@pytest.mark.parametrize("cyclic", [True, False])
def test_rows_of_many_phases_in_one_gather_equal_single_frames(cyclic):
    rng = np.random.default_rng(5)
    inner = LinearBlender(rng.normal(size=(10, 3, 40, 3)).astype(np.float32), cyclic)
    blender = PhaseTableBlender(inner, 10, cyclic, after=1)
    w = np.array([0.1, 0.6, 0.3])
    table = blender.lookup(w)
    phases = [0.0, 1.0, 0.5, *rng.random(13)]
    R = table.rows_at(phases)
    assert R.shape == (len(phases), 40 * 3) and R.dtype == np.float32
    for row, phase in zip(R, phases):
        np.testing.assert_allclose(row.reshape(-1, 3), inner.blend(w, phase), atol=2e-6)


def test_a_scaled_table_interpolates_to_the_scaled_blend_within_its_clip():
    rng = np.random.default_rng(6)
    inner = LinearBlender(rng.normal(size=(8, 2, 30, 3)).astype(np.float32), True)
    table = PhaseTableBlender(inner, 8, True, after=1).lookup(np.array([0.3, 0.7]))
    scale, offset = np.array([2.0, 3.0, 4.0]), np.array([10.0, 20.0, 30.0])
    scaled = table.scaled(scale, offset)
    assert table.scaled(scale, offset) is scaled           # built once
    for phase in rng.random(10):
        np.testing.assert_allclose(scaled.at(phase), table.at(phase) * scale + offset, atol=1e-4)
    clipped = table.scaled(scale, offset, 0.0, 25.0)
    values = clipped.rows_at(rng.random(50))
    assert values.min() >= 0.0 and values.max() <= 25.0


def test_tables_in_use_are_not_replaced_so_many_viewers_never_thrash():
    rng = np.random.default_rng(7)
    inner = LinearBlender(rng.normal(size=(8, 2, 50, 3)).astype(np.float32), True)
    now = [0.0]
    blender = PhaseTableBlender(inner, 8, True, capacity=2, after=1, idle=1.0, clock=lambda: now[0])
    weights = [np.array([1.0 - k / 10, k / 10]) for k in range(5)]
    for _ in range(20):                      # five viewers round-robin, all active
        for w in weights:
            np.testing.assert_allclose(blender.blend(w, 0.3), inner.blend(w, 0.3), atol=2e-6)
        now[0] += 0.05
    assert blender.builds == 2               # the first two got tables, the others blend directly
    now[0] += 2.0                            # everyone idle: a new weight vector replaces the oldest
    assert blender.lookup(np.array([0.5, 0.5])) is not None and blender.builds == 3


@pytest.mark.parametrize("K", [1, 8, 9, 20])
def test_rows_cast_is_rows_at_cast_exactly(K):
    rng = np.random.default_rng(K)
    for cyclic in (True, False):
        table = PhaseTable((rng.random((12, 50, 3)) * 60000).astype(np.float32), cyclic=cyclic)
        phases = (rng.random(K) * 1.2 - 0.1).tolist() + [0.0, 1.0, 11 / 12, 1 - 1e-17]  # edges, and outside [0, 1]
        for dtype in ("<u2", "<f4"):
            cast = table.rows_cast(phases, dtype)
            assert cast.dtype == np.dtype(dtype) and np.array_equal(cast, table.rows_at(phases).astype(dtype))

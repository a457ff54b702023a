"""Hybrid corrections and their file encoding (index lists or bitmasks per row)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.blend.corrections import CorrectionBuilder, Corrections, mask_rows, vector_lengths


def corrections_from_rows(rows, n_vertices, n_phases=1):
    """Corrections holding ``rows`` (lists of vertex indices), values counting up from 1."""
    counts = [len(r) for r in rows]
    vertex = np.concatenate([np.sort(np.asarray(r, dtype=np.int64)) for r in rows] + [np.zeros(0, np.int64)])
    value = (np.arange(3 * len(vertex)) % 255 - 127).astype(np.int8).reshape(-1, 3)
    return Corrections(n_phases=n_phases, n_vertices=n_vertices,
                       pointer=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
                       vertex=vertex.astype(np.uint16 if n_vertices <= 65536 else np.uint32), value=value,
                       scale=np.linspace(1e-4, 2e-4, len(rows)).astype(np.float32))


def assert_same(a, b):
    assert (a.n_phases, a.n_vertices) == (b.n_phases, b.n_vertices)
    for name in ("pointer", "vertex", "value", "scale"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def test_a_row_is_a_bitmask_exactly_when_that_is_smaller():
    # 1,000 vertices: a bitmask is 125 bytes; 62 entries are 124 bytes of indices, 63 are 126.
    np.testing.assert_array_equal(mask_rows([0, 1, 62, 63, 1000], 1000), [False, False, False, True, True])
    # Above 65,536 vertices indices take 4 bytes: 100,000 vertices -> 12,500-byte bitmasks.
    np.testing.assert_array_equal(mask_rows([3125, 3126], 100_000), [False, True])


def test_file_arrays_of_mixed_rows():
    rows = [[], [5, 7], list(range(0, 1000, 3)), [999], list(range(1000))]
    corrections = corrections_from_rows(rows, 1000)
    arrays = corrections.to_arrays()
    assert arrays["mask"].shape == (2, 125) and arrays["mask"].dtype == np.uint8
    np.testing.assert_array_equal(arrays["vertex"], [5, 7, 999])
    assert arrays["mask"][0, 0] == 0b01001001  # vertices 0, 3 and 6: bits 0, 3, 6 of byte 0
    assert np.all(arrays["mask"][1] == 255)
    assert corrections.nbytes() == sum(a.nbytes for a in arrays.values())
    assert corrections.nbytes() == 6 * 8 + 3 * 2 + 2 * 125 + corrections.value.nbytes + 5 * 4
    assert_same(Corrections.from_arrays(1, 1000, arrays), corrections)


@settings(max_examples=40, deadline=None)
@given(n_vertices=st.sampled_from([1, 9, 64, 333, 70_000]), data=st.data())
def test_encoding_round_trips_exactly(n_vertices, data):
    n_rows = data.draw(st.integers(0, 6))
    rows = []
    for _ in range(n_rows):
        size = data.draw(st.integers(0, min(n_vertices, 5000)))
        seed = data.draw(st.integers(0, 2**16))
        rows.append(np.random.default_rng(seed).choice(n_vertices, size, replace=False))
    corrections = corrections_from_rows(rows, n_vertices)
    arrays = corrections.to_arrays()
    assert corrections.nbytes() == sum(a.nbytes for a in arrays.values())
    assert_same(Corrections.from_arrays(1, n_vertices, arrays), corrections)


def test_inconsistent_arrays_are_refused():
    arrays = corrections_from_rows([list(range(100)), [3]], 1000).to_arrays()
    with pytest.raises(ValueError, match="bitmask rows"):
        Corrections.from_arrays(1, 1000, {**arrays, "mask": arrays["mask"][:0]})
    bad = arrays["mask"].copy()
    bad[0, 120] = 1
    with pytest.raises(ValueError, match="sets 101 vertices"):
        Corrections.from_arrays(1, 1000, {**arrays, "mask": bad})


def test_builder_stores_what_it_returns():
    rng = np.random.default_rng(0)
    delta = rng.normal(scale=0.004, size=(3, 500, 3))
    builder = CorrectionBuilder(3, 500)
    builder.add_empty()
    stored = builder.add(delta, threshold=0.005)
    corrections = builder.finish()
    assert corrections.n_references == 2
    np.testing.assert_array_equal(corrections.dense(1), stored)
    assert np.all(np.linalg.norm(delta[np.linalg.norm(stored, axis=2) == 0], axis=1) <= 0.005)
    assert_same(Corrections.from_arrays(3, 500, corrections.to_arrays()), corrections)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_vector_lengths_are_numpys_norms_to_the_bit(dtype):
    """The hybrid build's error lengths: faster than np.linalg.norm, and the same bits, so the
    corrections kept and pruned against epsilon are the same."""
    rng = np.random.default_rng(3)
    x = (rng.standard_normal((4, 7, 5000, 3)) * 10.0 ** rng.uniform(-6, 1, (4, 7, 5000, 1))).astype(dtype)
    x[0, 0, :3] = [[0.0, 0.0, 0.0], [np.inf, 1.0, 0.0], [-0.0, 3.0, 4.0]]
    lengths = vector_lengths(x)
    assert lengths.dtype == dtype and lengths.shape == (4, 7, 5000)
    assert np.array_equal(lengths, np.linalg.norm(x, axis=-1))
    assert np.array_equal(vector_lengths(x[:, ::2]), np.linalg.norm(x[:, ::2], axis=3))  # a strided view
    assert list(lengths[0, 0, :3]) == [0.0, np.inf, 5.0]

"""The stream's compiled row loops (engine/blend/compiled.py) against their numpy formulations,
byte for byte, and the parameter map's compiled Newton solve against its Python formulation."""

import math

import numpy as np
import pytest

from engine.blend.compiled import combine_rows, interpolate_at, warm_up
from engine.blend.many import aligned_rows


@pytest.mark.parametrize("cyclic", [True, False])
def test_interpolate_at_is_numpys_difference_multiply_add_and_cast(cyclic):
    """A frame between samples p0 and p1: rows[p0] + a (rows[p1] - rows[p0]) in float32, the
    difference taken in the pass; the bytes numpy's formulation gives (the float32 subtraction a
    table of stored differences held: the frames of the tables before this one)."""
    from engine.blend.phase import phase_samples

    rng = np.random.default_rng(1)
    rows = (250 + rng.random((9, 5000)) * 64500).astype(np.float32)  # a q16 table: codes stay in range
    phases = np.concatenate([rng.random(13), [0.0, 1.0, 8 / 9, 1 - 1e-17, -0.2, 1.3]])
    samples = [phase_samples(t, 9, cyclic) for t in phases]
    p0, p1 = [s[0] for s in samples], [s[1] for s in samples]
    a = np.array([s[2] for s in samples], dtype=np.float32)
    stored = np.empty_like(rows)  # the differences the tables used to store
    np.subtract(rows[1:], rows[:-1], out=stored[:-1])
    stored[-1] = rows[0] - rows[-1] if cyclic else 0.0
    expected = np.take(stored, p0, axis=0)
    expected *= a[:, None]
    expected += rows[p0]
    assert np.array_equal(np.take(rows, p1, axis=0) - rows[p0], np.take(stored, p0, axis=0))
    for dtype in ("<f4", "<u2"):
        out = interpolate_at(rows, phases, cyclic, np.empty((len(phases), 5000), dtype=dtype))
        assert out.tobytes() == expected.astype(dtype).tobytes()


def _terms(rng, K, R, P):
    counts = rng.integers(0, 9, K)
    counts[:3] = 1, 6, 4  # and the shapes summed in one pass (a hybrid frame's three or two references)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    T = int(starts[-1])
    return (rng.integers(0, R, T).astype(np.int64), rng.integers(0, P, T).astype(np.int64),
            rng.random(T).astype(np.float32), starts)


@pytest.mark.parametrize("m", [7, 2048, 6001])  # under, at and across the cache block
def test_combine_rows_sums_in_float32_in_order_and_encodes_as_the_quantiser(m):
    rng = np.random.default_rng(m)
    stack = rng.normal(size=(5, 4, m)).astype(np.float32)
    ref, phase, coef, starts = _terms(rng, 11, 5, 4)
    expected = np.zeros((11, m), dtype=np.float32)
    for k in range(11):
        for t in range(starts[k], starts[k + 1]):
            term = stack[ref[t], phase[t]] * coef[t]  # float32 product, then a float32 sum
            expected[k] = term if t == starts[k] else term + expected[k]
    for out in (np.empty((11, m), dtype=np.float32), aligned_rows(11, m)):
        assert combine_rows(stack, ref, phase, coef, starts, out).tobytes() == expected.tobytes()
    assert not expected[starts[1:] == starts[:-1]].any()  # a frame without terms is zero
    scale = np.tile(np.float32([9000.0, 12000.0, 30000.0]), m // 3 + 1)[:m]
    offset = np.tile(np.float32([30000.5, 20000.5, 0.5]), m // 3 + 1)[:m]
    codes = combine_rows(stack, ref, phase, coef, starts, np.empty((11, m), dtype=np.uint16), (scale, offset))
    q = expected * scale + offset
    np.clip(q, np.float32(0.0), np.float32(65535.0), out=q)
    assert codes.tobytes() == q.astype("<u2").tobytes()
    assert (codes == 0).any() and (codes == 65535).any()


def test_the_quantisers_codes_are_numpys_float32_steps():
    from server.codecs import Quantiser

    rng = np.random.default_rng(5)
    V = rng.normal(size=(500, 3)).astype(np.float32)
    quantiser = Quantiser((np.float32([-1.5, -1.0, -2.0]), np.float32([1.5, 1.2, 2.0])), 500)
    q = V.reshape(-1) * quantiser._scale + quantiser._offset
    np.clip(q, np.float32(0.0), np.float32(65535.0), out=q)
    assert quantiser.encode(V) == q.astype("<u2").tobytes()
    assert (q <= 0).any() and (q >= 65535).any()  # some clamp at each end
    assert quantiser.encode(V.astype(np.float64)[::-1][::-1]) == quantiser.encode(V)  # any layout and type
    with pytest.raises(ValueError, match="expected 500 vertices, got 499"):
        quantiser.encode(V[:-1])


def _newton_square_python(values, last, ranges, p, u):
    """The Python formulation the compiled solve replaced (engine/parameters/parameter_map.py
    before it), kept here as its reference."""
    s0, s1 = ranges
    q0, q1 = p
    x0, x1 = u
    norm = None
    for _ in range(21):
        x = min(max(x0, 0.0), 1.0) * last
        y = min(max(x1, 0.0), 1.0) * last
        i, j = min(int(x), last - 1), min(int(y), last - 1)
        a, b = x - i, y - j
        row0, row1 = values[i], values[i + 1]
        (c00, d00), (c10, d10), (c01, d01), (c11, d11) = row0[j], row1[j], row0[j + 1], row1[j + 1]
        wa, wb = 1.0 - a, 1.0 - b
        at0 = wa * wb * c00 + a * wb * c10 + wa * b * c01 + a * b * c11
        at1 = wa * wb * d00 + a * wb * d10 + wa * b * d01 + a * b * d11
        r0, r1 = (at0 - q0) / s0, (at1 - q1) / s1
        norm_here = math.sqrt(r0 * r0 + r1 * r1)
        if norm is not None and norm_here >= norm:
            break
        u, at, norm = [x0, x1], [at0, at1], norm_here
        if norm < 1e-9:
            break
        j00, j01 = last * (wb * (c10 - c00) + b * (c11 - c01)), last * (wa * (c01 - c00) + a * (c11 - c10))
        j10, j11 = last * (wb * (d10 - d00) + b * (d11 - d01)), last * (wa * (d01 - d00) + a * (d11 - d10))
        det = j00 * j11 - j01 * j10
        if abs(det) <= 1e-12 * max(abs(j00 * j11), abs(j01 * j10), 1e-30):
            return None
        e0, e1 = at0 - q0, at1 - q1
        x0 = min(max(u[0] - (j11 * e0 - j01 * e1) / det, 0.0), 1.0)
        x1 = min(max(u[1] - (j00 * e1 - j10 * e0) / det, 0.0), 1.0)
    return u, at


def test_the_compiled_newton_solve_gives_the_python_solves_numbers():
    from engine.parameters.layout import Layout
    from engine.parameters.parameter_map import ParameterMap

    rng = np.random.default_rng(3)
    axis = np.linspace(0.0, 1.0, 11)
    A, B = np.meshgrid(axis, axis, indexing="ij")
    values = np.stack([1.5 * A + 0.3 * np.sin(3 * B) + 0.1, 2.0 * B - 0.4 * A * B], axis=-1)
    values[4:6, 4:6, 1] = values[4, 4, 1]  # a flat patch: singular Jacobians there
    pm = ParameterMap(layout=Layout(kind="grid", n_sources=4, corners=[0, 1, 2, 3]), names=["speed", "turn"],
                      units=["m/s", "rad/s"], axes=[axis, axis], values=values)
    singular = 0
    for _ in range(2000):
        p = [rng.uniform(-0.3, 2.2), rng.uniform(-0.6, 2.3)]
        u = rng.random(2).tolist()
        expected = _newton_square_python(values.tolist(), 10, pm.ranges.tolist(), p, u)
        assert pm._newton_square(p, u) == expected  # the same floats, not merely close
        singular += expected is None
    assert singular > 0


def test_the_nearest_dense_sample_is_numpys_argmin():
    """A cold parameter solve starts from the dense sample nearest the request (scaled by the
    ranges): the compiled search gives numpy's index, ties to the first."""
    from engine.parameters.parameter_map import _nearest_scaled

    rng = np.random.default_rng(6)
    for k in (1, 2, 3):
        points = np.round(rng.random((3000, k)) * 20) / 20  # a coarse grid: many exact ties
        points[1500] = points[10]
        ranges = rng.uniform(0.1, 3.0, k)
        for p in rng.uniform(-0.2, 1.2, (300, k)).tolist() + [points[10].tolist()]:
            p = np.array(p)
            assert _nearest_scaled(points, p, ranges) == int(np.argmin(np.linalg.norm((points - p) / ranges, axis=1)))


def test_warm_up_compiles_every_signature_the_stream_uses():
    """After ``warm_up`` (a server's start), the stream's calls compile nothing new."""
    from engine.blend import compiled
    from engine.parameters import parameter_map

    warm_up()
    kernels = (compiled._interpolate_at, compiled._combine_rows, compiled._encode_q16, compiled._hybrid_terms,
               parameter_map._newton_square_compiled, parameter_map._nearest_scaled)
    before = [len(kernel.signatures) for kernel in kernels]
    assert all(before)
    rng = np.random.default_rng(4)
    stack = rng.normal(size=(3, 4, 30)).astype(np.float32)
    terms = _terms(rng, 5, 3, 4)
    for out in (aligned_rows(5, 30), np.empty((5, 30), dtype=np.float32)):  # ManyBlender's, and plain rows
        combine_rows(stack, *terms, out)
    combine_rows(stack, *terms, np.empty((5, 30), dtype=np.uint16), (np.ones(30, np.float32), np.zeros(30, np.float32)))
    for dtype in ("<f4", "<u2"):
        for cyclic in (True, False):
            compiled.interpolate_at(stack[0], rng.random(2), cyclic, np.empty((2, 30), dtype))
    parameter_map._newton_square_compiled(rng.random((3, 3, 2)), 2, 1.0, 1.0, 0.2, 0.3, 0.1, 0.9)
    parameter_map._nearest_scaled(rng.random((5, 2)), rng.random(2), np.ones(2))
    # a space's parameter map holds mapped, read-only arrays: its solves compile nothing new either
    from engine.parameters.layout import Layout

    axis = np.linspace(0.0, 1.0, 5)
    values = np.stack(np.meshgrid(axis, 2 * axis, indexing="ij"), axis=-1)
    values.setflags(write=False)
    pm = parameter_map.ParameterMap(layout=Layout(kind="grid", n_sources=4, corners=[0, 1, 2, 3]),
                                    names=["speed", "turn"], units=["m/s", "rad/s"], axes=[axis, axis], values=values)
    pm.solve([0.3, 1.1])
    pm.solve([0.35, 1.0], start=[0.3, 0.5])
    compiled.encode_q16(stack[0, 0], stack[0, 1], stack[0, 2])
    from engine.blend.simplex import SimplexTree  # ManyBlender's terms: a tree's arrays, a batch's weights and phases

    tree = SimplexTree(3)
    W = rng.random((4, 3))
    for cyclic in (True, False):
        compiled.hybrid_terms(W / W.sum(axis=1, keepdims=True), np.array([0.1, 0.5, 0.2, 0.9]), tree.children,
                              tree.split, tree.cells, 6, cyclic)
    assert [len(kernel.signatures) for kernel in kernels] == before

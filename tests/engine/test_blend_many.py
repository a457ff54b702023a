"""ManyBlender: K blends in one pass give the blender's frames (to float32 rounding), and each row
the same bytes whatever else is in the batch."""

import numpy as np
import pytest

from engine.blend import HybridBlender, LinearBlender, build_hybrid
from engine.blend.many import ManyBlender
from engine.blend.phase import phase_of_sample


def _hybrid(cyclic, n_sources=4, n_phases=6, n_vertices=40, depth=3):
    """A hybrid blender of random sources whose 'non-linear' blend bends the linear one, every
    cell split to ``depth`` (real references and corrections)."""
    rng = np.random.default_rng(11)
    sources = rng.normal(size=(n_phases, n_sources, n_vertices, 3)).astype(np.float32)
    bend = rng.normal(size=(n_phases, n_vertices, 3))

    def linear(w):
        w = np.asarray(w, float) / np.sum(w)
        return np.einsum("i,pinc->pnc", w, sources.astype(np.float64))

    def nonlinear(w):
        w = np.asarray(w, float) / np.sum(w)
        return linear(w) + 0.3 * np.prod(np.sqrt(w[:2])) * bend + 0.1 * np.sin(3 * w[2]) * bend

    tree, corrections, _ = build_hybrid(linear, nonlinear, n_sources, n_phases, n_vertices, epsilon=1e-3,
                                        uniform_depth=depth)
    return HybridBlender(sources, tree, corrections, cyclic), linear, nonlinear


def _weights(n_sources, count, seed):
    rng = np.random.default_rng(seed)
    W = rng.dirichlet(np.ones(n_sources), count)
    W[::3, -1] = 0.0                       # on a face of the simplex (a layout's sheet)
    W[1] = np.eye(n_sources)[2]            # a source itself
    W[2] = 2.5 * W[2]                      # not normalised
    phases = rng.random(count)
    phases[:4] = [0.0, 1.0, phase_of_sample(2, 6, True), 0.999999]
    return W, phases


@pytest.mark.parametrize("cyclic", [True, False])
@pytest.mark.parametrize("kind", ["linear", "hybrid"])
def test_many_blends_equal_the_blender_and_do_not_depend_on_the_batch(kind, cyclic):
    if kind == "hybrid":
        blender = _hybrid(cyclic)[0]
    else:
        rng = np.random.default_rng(12)
        blender = LinearBlender(rng.normal(size=(6, 4, 40, 3)).astype(np.float32), cyclic)
    many = ManyBlender(blender)
    W, phases = _weights(4, 24, seed=13)
    rows = many.blend(W, phases)
    assert rows.shape == (24, 120) and rows.dtype == np.float32
    for w, phase, row in zip(W, phases, rows):
        np.testing.assert_allclose(row.reshape(-1, 3), blender.blend(w, phase), atol=5e-6)
    alone = np.stack([many.blend(W[k:k + 1], phases[k:k + 1])[0] for k in range(len(W))])
    assert alone.tobytes() == rows.tobytes()
    reversed_rows = many.blend(W[::-1], phases[::-1])
    assert reversed_rows[::-1].tobytes() == rows.tobytes()
    assert all(row.flags.c_contiguous and row.ctypes.data % 64 == 0 for row in rows)
    if kind == "linear":  # the same BLAS product as LinearBlender.blend: the same bytes
        assert all(row.tobytes() == blender.blend(w, phase).tobytes() for w, phase, row in zip(W, phases, rows))


def test_hybrid_rows_interpolate_the_references_nodal_blends():
    """In a leaf, the hybrid is the barycentric mix of its references' hybrid blends (eq. 3): a
    weight half-way between two references of a leaf is their mean, at any phase; the rows of a
    reference are the blender's blends at the phase samples."""
    blender = _hybrid(True)[0]
    many = ManyBlender(blender)
    references = blender.tree.references
    a, b = references[0], references[len(references) - 1]
    leaf, _ = blender.tree.locate(0.5 * (a + b))
    cell = blender.tree.cells[leaf]
    r0, r1 = cell[0], cell[1]
    w = 0.5 * (references[r0] + references[r1])
    for phase in (0.1, 0.55):
        expected = 0.5 * (blender.blend(references[r0], phase).astype(np.float64)
                          + blender.blend(references[r1], phase))
        np.testing.assert_allclose(many.blend([w], [phase])[0].reshape(-1, 3), expected, atol=5e-6)
    rows = many.reference_rows(r1)
    assert rows.shape == (6, 120)
    assert rows[4].tobytes() == blender.blend(references[r1], phase_of_sample(4, 6, True)).tobytes()


def test_only_linear_and_hybrid_blenders_and_matching_shapes():
    with pytest.raises(TypeError, match="linear or hybrid"):
        ManyBlender(object())
    blender = LinearBlender(np.zeros((4, 2, 5, 3), np.float32), True)
    with pytest.raises(ValueError, match="K phases"):
        ManyBlender(blender).blend([[1.0, 0.0]], [0.1, 0.2])


@pytest.mark.parametrize("kind", ["linear", "hybrid"])
def test_q16_codes_in_the_blend_are_the_quantisers_codes_of_its_rows(kind):
    """``blend(..., codes)`` makes the q16 codes in the same pass: byte for byte the quantiser's
    encoding of the float32 rows (what a client blended alone, or given f32, decodes to)."""
    from server.codecs import Quantiser

    if kind == "hybrid":
        blender = _hybrid(False)[0]
    else:
        blender = LinearBlender(np.random.default_rng(14).normal(size=(6, 4, 40, 3)).astype(np.float32), False)
    many = ManyBlender(blender)
    W, phases = _weights(4, 17, seed=15)
    rows = many.blend(W, phases)
    lo, hi = rows.reshape(-1, 3).min(axis=0), rows.reshape(-1, 3).max(axis=0)
    quantiser = Quantiser((lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo)), 40)  # some values clamp
    codes = many.blend(W, phases, quantiser.codes)
    assert codes.dtype == np.dtype("<u2") and codes.shape == (17, 120)
    for row, code in zip(rows, codes):
        assert code.tobytes() == quantiser.encode(row.reshape(-1, 3))
    assert (codes == 0).any() and (codes == 65535).any()


def _terms_in_python(blender, W, phases):
    """The Python that made a hybrid batch's terms before ``hybrid_terms`` (engine/blend/compiled.py),
    kept as its reference."""
    from engine.blend.phase import phase_samples

    children, split, cells = blender._children, blender._split, blender.tree.cells.tolist()
    refs, samples, coefs, starts = [], [], [], [0]
    for lam, phase in zip((W / W.sum(axis=1, keepdims=True)).tolist(), phases):
        node = 0
        while children[node][0] >= 0:
            i, j = split[node]
            li, lj = lam[i], lam[j]
            if li >= lj:
                lam[i], lam[j] = li - lj, 2.0 * lj
                node = children[node][0]
            else:
                lam[j], lam[i] = lj - li, 2.0 * li
                node = children[node][1]
        p0, p1, a = phase_samples(phase, blender.n_phases, blender.cyclic)
        for g, r in zip(lam, cells[node]):
            if g <= 0.0:
                continue
            for p, c in ((p0, g * (1.0 - a)), (p1, g * a)):
                if c != 0.0:
                    refs.append(r)
                    samples.append(p)
                    coefs.append(c)
        starts.append(len(refs))
    return (np.array(refs, dtype=np.int64), np.array(samples, dtype=np.int64), np.array(coefs, dtype=np.float32),
            np.array(starts, dtype=np.int64))


@pytest.mark.parametrize("cyclic", [True, False])
def test_hybrid_terms_are_the_python_walks(cyclic):
    """The compiled terms (leaf, barycentric coordinates, phase samples) are the Python's, bit for bit."""
    from engine.blend.compiled import hybrid_terms

    blender = _hybrid(cyclic)[0]
    W, phases = _weights(4, 40, seed=16)
    tree = blender.tree
    terms = hybrid_terms(W / W.sum(axis=1, keepdims=True), np.array(phases), tree.children, tree.split, tree.cells,
                         blender.n_phases, cyclic)
    for got, expected in zip(terms, _terms_in_python(blender, W, phases)):
        assert got.dtype == expected.dtype and got.tobytes() == expected.tobytes()

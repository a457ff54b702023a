"""Linear, exact non-linear and hybrid blending (paper section 4.1, eq. 3)."""

import numpy as np
import pytest
import trimesh

from engine.blend import (
    FrameDecomposer,
    HybridBlender,
    LinearBlender,
    NonlinearBlender,
    PhasedNonlinearBlender,
    SimplexTree,
    VolumetricEmbedding,
    build_hybrid,
    decompose_frames,
    phase_of_sample,
)
from engine.motion_space import SourceClip, prepare_sources
from engine.rotations import rot_y
from engine.surface import enclosed_volume, model_size
from engine.synthetic import animate, build_body, gait

P = 8


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


@pytest.fixture(scope="module")
def embedding(body):
    return VolumetricEmbedding.from_surface(body.V, body.F)


@pytest.fixture(scope="module")
def space3(body, embedding):
    """Three gait sources on a phase grid with their blenders."""
    clips = []
    for speed in (0.9, 1.8, 3.2):
        motion = gait(body.skeleton, speed, cycles=2.0, start_phase=0.0)
        clips.append(SourceClip(f"g{speed}", animate(body, motion), motion.fps, True, motion.frames_per_cycle))
    sources = prepare_sources(clips, body.F, body.V, P).samples.astype(np.float32)
    frames = sources.reshape(-1, sources.shape[2], 3)
    q, s, d = decompose_frames(FrameDecomposer(embedding), frames)
    nonlinear = PhasedNonlinearBlender(NonlinearBlender(embedding, q, s, d, frames), P, 3, cyclic=True)
    return sources, LinearBlender(sources, cyclic=True), nonlinear


def test_simplex_location_reconstructs_the_weights():
    tree = SimplexTree(3)
    rng = np.random.default_rng(0)
    for _ in range(6):
        for leaf in tree.leaves():
            if rng.uniform() < 0.7:
                tree.bisect(leaf)
    for w in rng.dirichlet(np.ones(3), 200):
        leaf, lam = tree.locate(w)
        assert leaf in tree.leaves()
        assert np.all(lam >= -1e-12) and lam.sum() == pytest.approx(1.0)
        np.testing.assert_allclose(lam @ tree.vertices(leaf), w, atol=1e-12)


def test_nonlinear_blend_gives_back_each_source_exactly(body, space3):
    sources, _, nonlinear = space3
    for i in range(3):
        for p in (0, 3):
            V = nonlinear.blend(np.eye(3)[i], phase_of_sample(p, P, True))
            assert np.abs(V - sources[p, i]).max() <= 1e-4 * model_size(body.V)  # 0.01% of model size


def test_linear_blend_is_the_weighted_average(space3):
    sources, linear, _ = space3
    w = np.array([0.2, 0.3, 0.5])
    np.testing.assert_allclose(linear.blend(2 * w, phase_of_sample(2, P, True)),
                               np.einsum("i,inc->nc", w, sources[2]), atol=1e-6)
    # Halfway between phase samples 2 and 3: the average of the two.
    np.testing.assert_allclose(linear.blend(w, 2.5 / P), 0.5 * (linear.blend(w, 2 / P) + linear.blend(w, 3 / P)),
                               atol=1e-6)


def test_nonlinear_differs_from_linear_where_limbs_rotate(body, space3):
    _, linear, nonlinear = space3
    w = np.array([0.5, 0.0, 0.5])
    difference = np.linalg.norm(nonlinear.blend(w, 0.25) - linear.blend(w, 0.25), axis=1)
    assert difference.max() > 0.01  # centimetres on the limbs ...
    torso = np.isin(body.segment, [body.skeleton.index(j) for j in ("pelvis", "spine")])
    assert np.median(difference[torso]) < 0.2 * difference.max()  # ... much less on the torso


@pytest.mark.parametrize("n_sources", [2, 3])
def test_hybrid_is_within_epsilon_of_nonlinear_on_a_weight_grid(space3, n_sources):
    sources, _, _ = space3
    if n_sources == 2:
        sources = np.ascontiguousarray(sources[:, [0, 2]])
    frames = sources.reshape(-1, sources.shape[2], 3)
    linear = LinearBlender(sources, cyclic=True)
    inner = space3[2].blender
    keep = [0, 2] if n_sources == 2 else [0, 1, 2]
    index = (np.arange(P)[:, None] * 3 + np.array(keep)).ravel()
    nonlinear = PhasedNonlinearBlender(
        NonlinearBlender(inner.embedding, inner.quaternions[index], inner.stretch[index], inner.detail[index],
                         frames), P, n_sources, cyclic=True)
    epsilon = 0.006
    tree, corrections, report = build_hybrid(linear.blend_all_phases, nonlinear.blend_all_phases, n_sources, P,
                                             sources.shape[2], epsilon=epsilon)
    assert report.references >= 1 and report.max_test_error <= epsilon
    hybrid = HybridBlender(sources, tree, corrections, cyclic=True)
    grid = np.linspace(0, 1, 7)
    weights = [np.array([1 - a, a]) for a in grid] if n_sources == 2 else \
        [np.array([a, b, 1 - a - b]) for a in grid for b in grid if a + b <= 1 + 1e-9]
    worst = 0.0
    for w in weights:
        exact = nonlinear.blend_all_phases(w)
        for p in range(P):
            worst = max(worst, np.linalg.norm(hybrid.blend(w, p / P) - exact[p], axis=1).max())
    assert worst <= epsilon * 1.02
    # Linear blending alone is far off: the corrections are doing the work.
    assert max(np.linalg.norm(linear.blend_all_phases(w) - nonlinear.blend_all_phases(w), axis=2).max()
               for w in weights) > 3 * epsilon


def test_the_hybrid_reports_every_cell_tested_and_every_pruning_check(space3):
    """The bisection's progress moves on every cell it tests, not only on splits: a build whose
    references hit their cap tested cells for minutes with its bar standing still."""
    sources, linear, nonlinear = space3
    calls = []
    _, _, report = build_hybrid(linear.blend_all_phases, nonlinear.blend_all_phases, 3, P, sources.shape[2],
                                epsilon=0.008, progress=lambda *call: calls.append(call))
    messages = [message for message, _, _ in calls]
    done = [d for _, d, _ in calls]
    totals = [t for _, _, t in calls]
    assert done == list(range(1, len(calls) + 1))   # one step a call, on one bar
    assert all(d <= t for d, t in zip(done, totals)) and totals[-1] == done[-1]   # a total that grows to the end
    assert max(totals[:-1]) > totals[0]   # the bisection found more cells than the first
    splits = [m for m in messages if m.startswith("split cell")]
    kept = [m for m in messages if " kept " in m]
    pruning = [m for m in messages if m.startswith("pruning")]
    assert len(splits) >= report.references >= 1
    assert len(kept) >= report.leaves  # every final leaf was tested once and kept
    assert pruning and pruning[-1].endswith(f"{len(pruning)} of {len(pruning)} measured")
    assert len(messages) == len(splits) + len(kept) + len(pruning)
    # with the cap reached at once, no cell splits and every test still shows
    messages.clear()
    _, _, capped = build_hybrid(linear.blend_all_phases, nonlinear.blend_all_phases, 3, P, sources.shape[2],
                                epsilon=0.008, max_references=0, progress=lambda m, d, t: messages.append(m))
    assert capped.references == 0 and any(" kept " in m for m in messages)


def test_hierarchical_corrections_equal_nodal_interpolation(space3):
    """The hot path's sum over split nodes equals eq. 3's interpolation in the leaf."""
    sources, linear, nonlinear = space3
    tree, corrections, _ = build_hybrid(linear.blend_all_phases, nonlinear.blend_all_phases, 3, P,
                                        sources.shape[2], epsilon=0.008)
    n = sources.shape[2]
    nodal = {r: np.zeros((P, n, 3)) for r in range(3)}
    split_ref = tree.split_references()
    for node in range(len(tree.cells)):  # parents before children: rebuild D from the residuals
        r = split_ref[node]
        if r >= 0 and r not in nodal:
            a, b = tree.split[node]
            cell = tree.cells[node]
            nodal[r] = 0.5 * (nodal[cell[a]] + nodal[cell[b]]) + corrections.dense(r, n)
    sparse = HybridBlender(sources, tree, corrections, cyclic=True, dense_above=n)   # every row scattered
    dense = HybridBlender(sources, tree, corrections, cyclic=True, dense_above=0)    # every row dense
    assert not sparse._dense and len(dense._dense) == np.count_nonzero(np.diff(corrections.pointer))
    for w in np.random.default_rng(1).dirichlet(np.ones(3), 20):
        leaf, g = tree.locate(w)
        expected = linear.blend_all_phases(w)[4] + sum(gk * nodal[r][4] for gk, r in zip(g, tree.cells[leaf]))
        for hybrid in (sparse, dense):
            np.testing.assert_allclose(hybrid.blend(w, 4 / P), expected, atol=2e-6)


def test_pruning_drops_only_entries_the_bound_does_not_need(space3):
    """Pruned corrections are a subset of the thresholded ones and keep every test point (and
    every reference) within margin * epsilon, measured with the corrections as stored."""
    sources, linear, nonlinear = space3
    n, epsilon, margin = sources.shape[2], 0.008, 0.9
    blends = {}

    def exact(w):  # both builds and the check below share the non-linear blends
        key = tuple(np.round(w, 12))
        if key not in blends:
            blends[key] = nonlinear.blend_all_phases(w)
        return blends[key]

    args = (linear.blend_all_phases, exact, 3, P, n)
    tree, full, _ = build_hybrid(*args, epsilon=epsilon, prune=False)
    pruned_tree, pruned, report = build_hybrid(*args, epsilon=epsilon)
    np.testing.assert_array_equal(pruned_tree.references, tree.references)  # same bisection
    assert len(pruned.vertex) < len(full.vertex) and pruned.nbytes() < full.nbytes()
    np.testing.assert_array_equal(pruned.scale, full.scale)
    for r in range(full.n_references):  # a subset, values unchanged
        kept = pruned.dense(r)
        np.testing.assert_array_equal(kept[np.any(kept != 0, axis=2)], full.dense(r)[np.any(kept != 0, axis=2)])
    hybrid = HybridBlender(sources, pruned_tree, pruned, cyclic=True)
    points = [w for leaf in pruned_tree.leaves() for w in pruned_tree.test_points(leaf, 4)]
    worst = max(np.linalg.norm(np.stack([hybrid.blend(w, p / P) for p in range(P)])
                               - exact(w / w.sum()), axis=2).max()
                for w in points + list(pruned_tree.references[3:]))
    assert worst <= margin * epsilon + 1e-6
    assert report.max_test_error <= margin * epsilon + 1e-6


def test_quantised_corrections_are_within_half_a_step(space3):
    sources, linear, nonlinear = space3
    tree, corrections, _ = build_hybrid(linear.blend_all_phases, nonlinear.blend_all_phases, 3, P,
                                        sources.shape[2], epsilon=0.003, keep_threshold=0.0, uniform_depth=1)
    r = 3  # the first reference: its residual is D_NL itself (sources have none)
    w = tree.references[r]
    exact = nonlinear.blend_all_phases(w) - linear.blend_all_phases(w)
    stored = corrections.dense(r, sources.shape[2])
    step = corrections.scale[r * P:(r + 1) * P]
    assert np.all(np.abs(stored - exact).max(axis=(1, 2)) <= 0.5 * step + 1e-7)
    assert corrections.value.dtype == np.int8


def _bent_capsule(angle, segments=16, start=-0.2, length=0.5):
    """A capsule along +Y bent by ``angle`` onto a circular arc between y = start and start + length.

    The classic bend deformer: the bent stretch keeps its length along the axis, its inner
    side is compressed as much as its outer side is stretched, so the volume is preserved.
    """
    capsule = trimesh.creation.capsule(height=1.0, radius=0.12, count=[segments, segments])
    V, F = trimesh.remesh.subdivide_to_size(capsule.vertices, capsule.faces, max_edge=0.08)
    V = np.asarray(V, dtype=float)[:, [0, 2, 1]]  # axis along Y
    V[:, 2] *= -1  # a reflection back to a proper rotation of the axes
    if angle == 0:
        return V, np.asarray(F)
    x, y, z = V.T
    R = length / angle
    s = np.clip(y - start, 0.0, length)
    extra = np.maximum(y - start - length, 0.0)
    phi = angle * s / length
    out = np.stack([-R + (R + x) * np.cos(phi) - extra * np.sin(phi),
                    np.where(y < start, y, start + (R + x) * np.sin(phi) + extra * np.cos(phi)), z], axis=1)
    return out, np.asarray(F)


def test_nonlinear_blend_preserves_volume_of_a_bending_limb():
    V0, F = _bent_capsule(0.0)
    if enclosed_volume(V0, F) < 0:
        F = F[:, ::-1]
    V1, _ = _bent_capsule(np.radians(120))
    embedding = VolumetricEmbedding.from_surface(V0, F)
    frames = np.stack([V0, V1]).astype(np.float32)
    q, s, d = decompose_frames(FrameDecomposer(embedding), frames)
    nonlinear = NonlinearBlender(embedding, q, s, d, frames)
    half_nl = nonlinear.blend_frames(np.array([0.5, 0.5]), [0, 1])
    half_linear = 0.5 * (V0 + V1)
    volume = enclosed_volume(V0, F)
    assert enclosed_volume(half_nl, F) == pytest.approx(volume, rel=0.03)
    assert enclosed_volume(half_linear, F) < 0.93 * volume  # linear blending collapses the bend
    assert enclosed_volume(V1, F) == pytest.approx(volume, rel=0.02)  # the bend itself keeps volume
    truth, _ = _bent_capsule(np.radians(60))
    assert np.abs(half_nl - truth).max() < 0.25 * np.abs(half_linear - truth).max()


def test_nonlinear_blend_of_a_rotation_is_the_half_rotation():
    box = trimesh.creation.box(extents=(0.6, 0.2, 0.1))
    box = box.subdivide().subdivide()
    V0, F = np.asarray(box.vertices) + [0.2, 0.0, 0.0], np.asarray(box.faces)
    centre = V0.mean(axis=0)
    V1 = (V0 - centre) @ rot_y(np.radians(90)).T + centre
    embedding = VolumetricEmbedding.from_surface(V0, F)
    frames = np.stack([V0, V1]).astype(np.float32)
    q, s, d = decompose_frames(FrameDecomposer(embedding), frames)
    half = NonlinearBlender(embedding, q, s, d, frames).blend_frames(np.array([0.5, 0.5]), [0, 1])
    expected = (V0 - centre) @ rot_y(np.radians(45)).T + centre
    error = np.linalg.norm(half - expected, axis=1).max()
    assert error < 2e-3 * model_size(V0)
    assert error < 0.02 * np.linalg.norm(0.5 * (V0 + V1) - expected, axis=1).max()  # linear cuts the corner


def test_a_triangle_soup_blends_as_its_welded_surface():
    """A soup (every face with three vertices of its own, as STL keeps a mesh) repeats each point
    once per face round it. The fit of the tets to each frame and the blend's placement counted
    every copy, so a soup blended up to millimetres from the same surface welded (the well
    connected points pulled harder). Copies now share one point's weight: the soup blends as the
    surface, and a surface without copies blends as before."""
    V0, F = _bent_capsule(0.0)
    V1, _ = _bent_capsule(np.radians(120))
    frames = np.stack([V0, V1]).astype(np.float32)
    soup_F = np.arange(3 * len(F)).reshape(-1, 3)
    soup_frames = frames[:, F.reshape(-1)]

    def half(frames, F):
        embedding = VolumetricEmbedding.from_surface(frames[0].astype(np.float64), F)
        q, s, d = decompose_frames(FrameDecomposer(embedding), frames)
        return embedding, NonlinearBlender(embedding, q, s, d, frames).blend_frames(np.array([0.3, 0.7]), [0, 1])

    welded, welded_half = half(frames, F)
    soup, soup_half = half(soup_frames, soup_F)
    assert welded.surface_share is None
    np.testing.assert_allclose(soup.surface_share, 1.0 / np.bincount(F.reshape(-1))[F.reshape(-1)])
    np.testing.assert_allclose(soup_half, welded_half[F.reshape(-1)], atol=1e-6 * model_size(V0))


def test_a_floating_piece_blends_as_a_solid_of_its_own():
    """A surface in two closed pieces (a bending limb and a box floating beside it that turns
    90 degrees and moves): the tet mesh has two parts; each blends non-linearly, and the box
    lands, turned half way, where the linear blend puts its centroid."""
    V0, F = _bent_capsule(0.0)
    if enclosed_volume(V0, F) < 0:
        F = F[:, ::-1]
    V1, _ = _bent_capsule(np.radians(90))
    box = trimesh.creation.box(extents=(0.16, 0.08, 0.08)).subdivide()
    B0, BF = np.asarray(box.vertices) + [0.6, 0.1, 0.0], np.asarray(box.faces)
    centre = B0.mean(axis=0)
    B1 = (B0 - centre) @ rot_y(np.radians(90)).T + centre + [0.1, 0.2, 0.0]
    F2 = np.vstack([F, BF + len(V0)])
    frames = np.stack([np.vstack([V0, B0]), np.vstack([V1, B1])]).astype(np.float32)
    embedding = VolumetricEmbedding.from_surface(frames[0].astype(np.float64), F2)
    q, s, d = decompose_frames(FrameDecomposer(embedding), frames)
    nonlinear = NonlinearBlender(embedding, q, s, d, frames)
    assert nonlinear.solver.n_parts == 2
    for k in (0, 1):   # each source given back
        e = np.eye(2)[k]
        np.testing.assert_allclose(nonlinear.blend_frames(e, [0, 1]), frames[k], atol=1e-3 * model_size(V0))
    half = nonlinear.blend_frames(np.array([0.5, 0.5]), [0, 1])
    piece = slice(len(V0), None)
    expected = (B0 - centre) @ rot_y(np.radians(45)).T + centre + [0.05, 0.1, 0.0]
    assert np.linalg.norm(half[piece] - expected, axis=1).max() < 1e-4
    assert enclosed_volume(half[:len(V0)], F) == pytest.approx(enclosed_volume(V0, F), rel=0.03)


def test_the_bisection_stops_at_its_budget_of_references():
    """Sources that blend badly everywhere bisected the whole simplex to the depth limit: a
    five-source build of unrelated takes was still at it after 19 minutes (session 18). The
    bisection adds at most ``max_references`` references, coarser cells first, and the report's
    test error says the bound is not met."""
    rng = np.random.default_rng(3)
    n_sources, n_phases, n_vertices = 4, 2, 40
    sources = rng.normal(size=(n_phases, n_sources, n_vertices, 3))
    bend = rng.normal(size=(n_phases, n_vertices, 3))

    def linear(w):
        w = np.asarray(w, float) / np.sum(w)
        return np.einsum("i,pinc->pnc", w, sources)

    def nonlinear(w):  # far from linear everywhere inside the simplex
        w = np.asarray(w, float) / np.sum(w)
        return linear(w) + (1 + np.sin(7 * w[0] + 5 * w[1])) * (w[0] * w[1] + w[1] * w[2] + w[2] * w[3]) * bend

    args = (linear, nonlinear, n_sources, n_phases, n_vertices)
    _, _, free = build_hybrid(*args, epsilon=1e-3, max_references=40)
    tree, _, capped = build_hybrid(*args, epsilon=1e-3, max_references=12)
    assert free.references > 12
    assert capped.references == 12 == len(tree.references) - n_sources
    assert capped.max_test_error > 1e-3 and capped.max_depth < free.max_depth


def test_a_smaller_cache_of_nonlinear_blends_gives_the_same_hybrid(monkeypatch):
    """The bisection's cache of non-linear blends is bounded (a five-source build of unrelated
    takes held 24 GB of them and was killed): with room for only 64, the same tree and
    corrections, from more evaluations."""
    import engine.blend.hybrid_build as hybrid

    rng = np.random.default_rng(5)
    sources = rng.normal(size=(2, 3, 30, 3))
    bend = rng.normal(size=(2, 30, 3))

    def linear(w):
        w = np.asarray(w, float) / np.sum(w)
        return np.einsum("i,pinc->pnc", w, sources)

    def nonlinear(w):
        w = np.asarray(w, float) / np.sum(w)
        return linear(w) + (w[0] * w[1] + 2 * w[1] * w[2]) * np.cos(4 * w[0]) * bend

    args = (linear, nonlinear, 3, 2, 30)
    tree, corrections, report = build_hybrid(*args, epsilon=2e-3)
    monkeypatch.setattr(hybrid, "CACHE_BYTES", 0)
    small_tree, small_corrections, small_report = build_hybrid(*args, epsilon=2e-3)
    assert report.references > 3 and small_report.references == report.references
    assert np.array_equal(small_tree.references, tree.references)
    for name in ("pointer", "vertex", "value", "scale"):
        assert np.array_equal(getattr(small_corrections, name), getattr(corrections, name)), name
    assert small_report.max_test_error == report.max_test_error
    assert small_report.nonlinear_evaluations > report.nonlinear_evaluations

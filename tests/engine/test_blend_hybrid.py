"""The hybrid's bisection is conforming: no reference hangs on a leaf's edge (issue 12).

Before, a cell split at the midpoint of an edge left the neighbour sharing that edge whole, so the
neighbour interpolated across a reference it did not see: on the demo's reach space the hybrid at
weight (0.25, 0.25, 0.5), itself a reference, was 269 mm from the non-linear blend.
"""

import numpy as np
import pytest

from engine.blend import SimplexTree, phase_of_sample
from engine.motion_space import MotionSpace, SourceClip, build_motion_space
from engine.parameters.sheet import between_weights, sheet_weights
from engine.parameters import Layout
from engine.synthetic import SequenceSpec, build_body, generate_sequence_data

EPSILON = 0.005


def _hanging(tree):
    """Leaves with a reference at the midpoint of one of their edges, found geometrically."""
    references = tree.references
    out = []
    for leaf in tree.leaves():
        W = references[tree.cells[leaf]]
        for i in range(len(W)):
            for j in range(i + 1, len(W)):
                if np.any(np.all(np.abs(references - 0.5 * (W[i] + W[j])) < 1e-12, axis=1)):
                    out.append(leaf)
    return out


def test_a_split_beside_an_unsplit_neighbour_leaves_a_hanging_reference():
    """What went wrong, on the bare tree: splitting one cell's edge (3, 2) but not its neighbour's."""
    tree = SimplexTree(3)
    tree.bisect(0)                                    # (1, 0, 0) - (0, 1, 0): reference 3
    tree.bisect(1)                                    # cell [0, 3, 2] on (0, 2): reference 4
    tree.bisect(2)                                    # cell [3, 1, 2] on (1, 2): reference 5
    second = [leaf for leaf in tree.leaves() if sorted(tree.cells[leaf]) == [2, 3, 5]][0]
    reference, is_new = tree.bisect(second)           # on (3, 2): (0.25, 0.25, 0.5)
    np.testing.assert_allclose(tree.references[reference], [0.25, 0.25, 0.5])
    assert len(_hanging(tree)) == 1 == len(tree.hanging_references())


def test_conforming_bisection_never_leaves_a_hanging_reference():
    rng = np.random.default_rng(2)
    for n_sources in (3, 4):
        tree = SimplexTree(n_sources)
        for _ in range(40):
            leaves = tree.leaves()
            _, _, nodes = tree.bisect_conforming(leaves[rng.integers(len(leaves))])
            assert nodes[0] in nodes and all(tree.children[node][0] >= 0 for node in nodes)
            assert _hanging(tree) == [] and tree.hanging_references() == []
        for w in rng.dirichlet(np.ones(n_sources), 50):  # the leaves still tile the simplex
            leaf, lam = tree.locate(w)
            np.testing.assert_allclose(lam @ tree.vertices(leaf), w, atol=1e-12)


@pytest.fixture(scope="module")
def reach_space(tmp_path_factory):
    """A small reach space like the demo's: low, middle and high reaches in a chain."""
    body = build_body(1000)
    clips = []
    for name, height in (("reach_low", 0.7), ("reach_mid", 1.3), ("reach_high", 1.95)):
        data = generate_sequence_data(body, SequenceSpec(name, "reach", {"height": height, "side": "r"}),
                                      fps=15.0, unstructured=False)
        clips.append(SourceClip(name, data["vertices"], 15.0, False))
    path = tmp_path_factory.mktemp("reach") / "reach.mspace"
    build_motion_space(path, clips, body.F, name="reach", n_phases=12, epsilon=EPSILON, rest=body.V,
                       parameters={"layout": Layout("chain", 3, chain=(0, 1, 2)), "names": ["reach_height"]})
    with MotionSpace.open(path) as space:
        yield space


def _worst(space, weights):
    """Largest hybrid - non-linear distance (m) over the phase samples, per weight vector."""
    hybrid, nonlinear = space.blender("hybrid"), space.blender("nonlinear")
    P = space.n_phases
    return np.array([max(np.linalg.norm(hybrid.blend(w, phase_of_sample(p, P, False))
                                        - nonlinear.blend(w, phase_of_sample(p, P, False)), axis=1).max()
                         for p in range(P)) for w in weights])


def test_reach_space_tree_conforms_and_holds_at_every_reference(reach_space):
    tree = reach_space.tree
    assert len(tree.references) > 4 and _hanging(tree) == []
    errors = _worst(reach_space, tree.references)
    assert errors.max() <= EPSILON, (tree.references[np.argmax(errors)], errors.max())


def test_reach_space_bound_holds_on_a_dense_sampling_of_its_sheet(reach_space):
    """The bound is enforced where the layout can go: every weight along the chain, 4x denser
    than the build's test weights (33 per chain)."""
    layout = reach_space.parameter_map.layout
    weights = np.array([layout.weights([u]) for u in np.linspace(0.0, 1.0, 129)])
    assert _worst(reach_space, weights).max() <= 1.02 * EPSILON


def test_longest_edge_among_those_the_points_straddle():
    """Points on one edge of the triangle: only that edge is split, however short it is."""
    tree = SimplexTree(3)
    tree.bisect(0, (0, 1))                                 # (0.5, 0.5, 0): cells [0, 3, 2], [3, 1, 2]
    first = tree.children[0][0]
    on_edge = np.array([[0.9, 0.1, 0.0], [0.7, 0.3, 0.0]])  # on (1, 0, 0) - (0.5, 0.5, 0)
    assert tree.longest_edge(first) == (0, 2)              # (1, 0, 0) - (0, 0, 1): longest
    assert tree.longest_edge(first, on_edge) == (0, 1)     # the edge the points lie on
    inside = np.array([[0.6, 0.2, 0.2]])                   # straddles every edge: the longest
    assert tree.longest_edge(first, inside) == (0, 2)
    corner = np.array([[1.0, 0.0, 0.0]])                   # straddles none: the longest
    assert tree.longest_edge(first, corner) == (0, 2)


def test_a_chain_layout_places_every_reference_on_the_chain(reach_space):
    """The chain low - mid - high runs along two edges of the weight triangle; references off it
    (e.g. on the low - high edge) would store corrections the player can never reach."""
    references = reach_space.tree.references
    assert len(references) > 4
    assert np.all((references[:, 0] == 0) | (references[:, 2] == 0)), references


def _grid_blends(seed=3, n_phases=2, n_vertices=40):
    """Linear and non-linear blends of four sources whose difference bends quickly across a grid
    layout's sheet (and vanishes at the sources, as a blend's does): between a coarse grid's test
    points it rises above what they see."""
    rng = np.random.default_rng(seed)
    sources = rng.normal(size=(n_phases, 4, n_vertices, 3))
    bend = 0.002 * rng.normal(size=(n_phases, n_vertices, 3))

    def linear(w):
        w = np.asarray(w, float) / np.sum(w)
        return np.einsum("i,pinc->pnc", w, sources)

    def nonlinear(w):
        w = np.asarray(w, float) / np.sum(w)
        shape = (1.0 - w @ w) * (np.sin(3 * w[0] + 4 * w[3]) + np.cos(3 * w[1] * w[2]))  # 0 at a source
        return linear(w) + shape * bend

    return sources, linear, nonlinear


def test_between_weights_lie_halfway_between_the_test_points():
    grid = Layout("grid", 4, corners=(0, 1, 2, 3))
    chain = Layout("chain", 3, chain=(0, 1, 2))
    assert between_weights(grid, 5).shape == (9 * 9 - 5 * 5, 4)
    assert between_weights(chain, 5).shape == (4, 3)
    np.testing.assert_allclose(between_weights(chain, 3), [chain.weights([0.25]), chain.weights([0.75])])
    tests = {tuple(np.round(w, 12)) for w in sheet_weights(grid, 5)}
    assert not any(tuple(np.round(w, 12)) in tests for w in between_weights(grid, 5))


def test_the_bound_is_checked_between_a_sheets_test_points():
    """On a two-dimensional sheet the bisection saw only its test points, and the hybrid was over
    epsilon between them (the demo's fan: 5.89 mm at epsilon 5 mm). With the check, every weight
    halfway between them is within epsilon, measured here by the runtime blender."""
    from engine.blend import HybridBlender, build_hybrid

    sources, linear, nonlinear = _grid_blends()
    grid = Layout("grid", 4, corners=(0, 1, 2, 3))
    tests, between = sheet_weights(grid, 5), between_weights(grid, 5)
    epsilon = 2e-3
    args = (linear, nonlinear, 4, sources.shape[0], sources.shape[2])
    P = sources.shape[0]
    flat = np.ascontiguousarray(sources, dtype=np.float32)  # (P, N, n, 3), as a space holds them

    def worst(tree, corrections, weights):
        hybrid = HybridBlender(flat, tree, corrections, False)
        return np.array([max(np.linalg.norm(hybrid.blend(w, phase_of_sample(p, P, False))
                                            - nonlinear(w)[p], axis=1).max() for p in range(P)) for w in weights])

    tree, corrections, unchecked = build_hybrid(*args, epsilon=epsilon, test_weights=tests)
    assert unchecked.check_points == 0 and np.isnan(unchecked.max_check_error)
    assert worst(tree, corrections, tests).max() <= 0.9 * epsilon + 1e-6
    assert worst(tree, corrections, between).max() > epsilon           # what the check is for

    tree, corrections, report = build_hybrid(*args, epsilon=epsilon, test_weights=tests, check_weights=between)
    errors = worst(tree, corrections, between)
    assert report.check_points == len(between) and report.check_added > 0 and report.check_rounds >= 2
    assert errors.max() <= epsilon + 1e-6 and abs(errors.max() - report.max_check_error) < 1e-5
    assert worst(tree, corrections, tests).max() <= 0.9 * epsilon + 1e-6
    again = build_hybrid(*args, epsilon=epsilon, test_weights=tests, check_weights=between)
    assert np.array_equal(again[0].references, tree.references)
    for name in ("pointer", "vertex", "value", "scale"):
        assert np.array_equal(getattr(again[1], name), getattr(corrections, name)), name

"""The hybrid's bisection is conforming: no reference hangs on a leaf's edge (issue 12).

Before, a cell split at the midpoint of an edge left the neighbour sharing that edge whole, so the
neighbour interpolated across a reference it did not see: on the demo's reach space the hybrid at
weight (0.25, 0.25, 0.5), itself a reference, was 269 mm from the non-linear blend.
"""

import numpy as np
import pytest

from engine.blend import SimplexTree, phase_of_sample
from engine.motion_space import MotionSpace, SourceClip, build_motion_space
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

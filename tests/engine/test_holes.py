import numpy as np
import pytest
import trimesh

from engine.holes import boundary_edges, boundary_loops, cap_holes, capped_volume
from engine.surface import enclosed_volume


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=2)


def test_closed_surface_has_no_boundary(sphere):
    assert len(boundary_edges(sphere.faces)) == 0
    assert boundary_loops(sphere.faces) == []
    V, F = cap_holes(sphere.vertices, sphere.faces)
    np.testing.assert_array_equal(F, sphere.faces)


def test_one_missing_triangle_is_one_loop_of_three_and_its_cap_restores_the_volume(sphere):
    F = sphere.faces[1:]
    loops = boundary_loops(F)
    assert len(loops) == 1 and sorted(loops[0]) == sorted(sphere.faces[0])
    V_capped, F_capped = cap_holes(sphere.vertices, F)
    assert len(V_capped) == len(sphere.vertices) + 1 and len(F_capped) == len(F) + 3
    np.testing.assert_array_equal(F_capped[:len(F)], F)  # the original faces stay first
    assert len(boundary_edges(F_capped)) == 0            # closed, orientation continued
    # the fan lies in the removed triangle's plane: the volume is the closed sphere's
    assert enclosed_volume(V_capped, F_capped) == pytest.approx(enclosed_volume(sphere.vertices, sphere.faces),
                                                                rel=1e-12)


def test_two_holes_two_loops_and_capped_volume_over_frames(sphere):
    top = sphere.vertices[sphere.faces].mean(axis=1)[:, 1] > 0.8
    bottom = sphere.vertices[sphere.faces].mean(axis=1)[:, 1] < -0.8
    F = sphere.faces[~(top | bottom)]
    loops = boundary_loops(F)
    assert len(loops) == 2
    frames = np.stack([sphere.vertices, 2.0 * sphere.vertices])
    volume = capped_volume(frames, F)
    assert volume[1] == pytest.approx(8.0 * volume[0], rel=1e-12)
    # flat caps cut off two spherical caps, so a little less than the closed sphere
    assert 0.8 * sphere.volume < volume[0] < sphere.volume

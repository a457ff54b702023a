"""Colour cues in alignment: on by default only where the meshes are fine enough to carry texture."""

import numpy as np
import pytest
import trimesh

from engine.align import AlignmentOptions, align_captures
from engine.align.captures import colours_carry_texture
from engine.mesh_io import Mesh


def _subdivided(V, F):
    mesh = trimesh.Trimesh(V, F, process=False).subdivide()
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_only_finely_sampled_meshes_count_as_textured(walk_capture):
    body, _, frames = walk_capture
    V, F = frames[0][0], frames[0][1]
    assert not colours_carry_texture(V, F)  # the test body: about 4% edges
    fine_V, fine_F = V, F
    for _ in range(2):  # each subdivision halves the edges
        fine_V, fine_F = _subdivided(fine_V, fine_F)
    assert colours_carry_texture(fine_V, fine_F)
    assert not colours_carry_texture(V, np.zeros((0, 3), dtype=np.int64))


@pytest.mark.parametrize("use_colors, expected", [("auto", False), (True, True), (False, False)])
def test_align_captures_reports_whether_colours_guided_the_matches(walk_capture, walk_aligner, use_colors, expected):
    _, _, frames = walk_capture
    meshes = [Mesh(vertices=f[0], faces=f[1], colors=f[2]) for f in frames[:2]]
    run = align_captures(meshes, [2], root=0, tets=(walk_aligner.V_tet, walk_aligner.T), use_colors=use_colors,
                         options=AlignmentOptions(levels=2, rounds=(2, 1)), repair=False)
    assert run.colour_cues is expected


def test_colour_cues_need_colours_on_every_frame(walk_capture, walk_aligner):
    _, _, frames = walk_capture
    meshes = [Mesh(vertices=frames[0][0], faces=frames[0][1], colors=frames[0][2]),
              Mesh(vertices=frames[1][0], faces=frames[1][1])]
    run = align_captures(meshes, [2], root=0, tets=(walk_aligner.V_tet, walk_aligner.T), use_colors=True,
                         options=AlignmentOptions(levels=2, rounds=(2, 1)), repair=False)
    assert run.colour_cues is False
    with pytest.raises(ValueError, match="use_colors"):
        align_captures(meshes, [2], root=0, use_colors="sometimes")

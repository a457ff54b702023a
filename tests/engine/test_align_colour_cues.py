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


def _tube(bend, length=1.6, radius=0.1, along=128, around=50):
    """An open tube of ``along`` x ``around`` vertices, straight or bent nine tenths of the way
    round a circle (``bend``): about the same edges and area, and a bounding box half as long."""
    s = np.linspace(0.0, length, along)
    a = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    S, A = np.meshgrid(s, a, indexing="ij")
    if bend:
        R = length / (1.8 * np.pi)
        theta = S / R
        r = R + radius * np.cos(A)
        P = np.stack([r * np.sin(theta), R - r * np.cos(theta), radius * np.sin(A)], axis=-1)
    else:
        P = np.stack([S, radius * np.cos(A), radius * np.sin(A)], axis=-1)
    V = P.reshape(-1, 3)
    i, j = np.meshgrid(np.arange(along - 1), np.arange(around), indexing="ij")
    a0, a1 = i * around + j, i * around + (j + 1) % around
    b0, b1 = a0 + around, a1 + around
    F = np.concatenate([np.stack([a0, b0, a1], -1).reshape(-1, 3), np.stack([a1, b0, b1], -1).reshape(-1, 3)])
    return V, F


def test_whether_colours_carry_texture_does_not_depend_on_the_pose():
    # the same finely sampled surface straight and bent: its bounding box halves, its edges and
    # area stay (a crouching root frame was once judged too coarse for its colours)
    straight, bent = _tube(False), _tube(True)
    assert np.ptp(bent[0], axis=0).max() < 0.5 * np.ptp(straight[0], axis=0).max()
    assert colours_carry_texture(*straight)
    assert colours_carry_texture(*bent)
    coarse_straight, coarse_bent = _tube(False, along=40, around=16), _tube(True, along=40, around=16)
    assert not colours_carry_texture(*coarse_straight)
    assert not colours_carry_texture(*coarse_bent)


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

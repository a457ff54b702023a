"""`morphspace blend` on meshes the project did not make, its progress display, and its errors."""

import re

import numpy as np
import pytest
import trimesh

from engine.mesh_io import read_mesh, write_obj, write_ply
from engine.surface import enclosed_volume
from server.cli import main


def _arm(angle):
    """A subdivided box 'arm' bent at its middle by ``angle`` about +Z (same topology for all)."""
    box = trimesh.creation.box(extents=(0.1, 0.6, 0.1))
    V, F = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=0.04)
    V = np.asarray(V, dtype=float)
    upper = np.clip(V[:, 1] / 0.1, 0.0, 1.0)[:, None]  # blend the rotation over y in [0, 0.1]
    c, s = np.cos(angle * upper[:, 0]), np.sin(angle * upper[:, 0])
    bent = V.copy()
    bent[:, 0] = c * V[:, 0] - s * V[:, 1]
    bent[:, 1] = s * V[:, 0] + c * V[:, 1]
    return bent, np.asarray(F)


@pytest.fixture(scope="module")
def arms(tmp_path_factory):
    folder = tmp_path_factory.mktemp("arms")
    V0, F = _arm(0.0)
    V1, _ = _arm(np.radians(100))
    write_obj(folder / "straight.obj", V0, F)
    write_ply(folder / "bent.ply", V1, F)  # mixed formats on purpose
    return folder, V0, V1, F


def test_blend_modes_write_meshes_and_nonlinear_keeps_volume(arms, capsys):
    folder, V0, V1, F = arms
    volume = enclosed_volume(V0, F)
    results = {}
    for mode in ("linear", "nonlinear", "hybrid"):
        out = folder / f"{mode}.obj"
        assert main(["blend", str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1", "1",
                     "--mode", mode, "--out", str(out)]) == 0
        mesh = read_mesh(out)
        np.testing.assert_array_equal(mesh.faces, F)
        results[mode] = mesh.vertices
    assert enclosed_volume(results["nonlinear"], F) == pytest.approx(volume, rel=0.03)
    assert enclosed_volume(results["linear"], F) < 0.97 * volume
    assert np.abs(results["hybrid"] - results["nonlinear"]).max() <= 0.005 * 1.05


def test_blend_weights_e0_give_back_the_first_mesh(arms):
    folder, V0, _, F = arms
    out = folder / "first.obj"
    assert main(["blend", str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1", "0",
                 "--mode", "nonlinear", "--out", str(out)]) == 0
    assert np.abs(read_mesh(out).vertices - V0).max() < 1e-4 * 0.6


def test_blend_compare_reports_errors(arms, capsys):
    folder, *_ = arms
    assert main(["blend", str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "0.5", "0.5",
                 "--mode", "hybrid", "--compare", "--out", str(folder / "cmp.obj")]) == 0
    captured = capsys.readouterr()
    out = captured.out
    for mode in ("linear ", "hybrid "):  # max and mean, each in the data's unit and in % of the model size
        assert re.search(rf"{mode} vs non-linear: max \d+\.\d\d+ mm \([\d.e+-]+% of model size\), "
                         rf"mean \d+\.\d\d+ mm \([\d.e+-]+% of model size\)", out), out
    # the % are of the model size the units line states (the straight arm alone is longer than the bent one)
    stated = float(re.search(r"the model is ([\d.]+) m across", captured.err).group(1))
    mm, pct = re.search(r"linear  vs non-linear: max (\d+\.\d\d+) mm \(([\d.e+-]+)% of model size\)", out).groups()
    assert float(mm) / 1000 / (float(pct) / 100) == pytest.approx(stated, rel=0.02)


def test_blend_shows_its_stages_on_stderr_and_keeps_stdout_and_output(arms, capsys):
    folder, V0, V1, F = arms
    inputs = [str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1", "3"]
    assert main(["blend", *inputs, "--mode", "linear", "--out", str(folder / "lin.obj")]) == 0
    captured = capsys.readouterr()
    assert re.fullmatch(rf"wrote {re.escape(str(folder / 'lin.obj'))}: linear blend of 2 meshes \({len(V0)} vertices\) "
                        r"with weights \[0.25, 0.75\] in \d+\.\d\d s, in the inputs' units \(m, up \+Y\)\n", captured.out)
    assert [stage for stage in ("read", "solve", "write") if f"{stage}: 100%" in captured.err] == ["read", "solve",
                                                                                                     "write"]
    np.testing.assert_allclose(read_mesh(folder / "lin.obj").vertices, 0.25 * V0 + 0.75 * V1, atol=1e-6)

    assert main(["blend", *inputs, "--mode", "hybrid", "--out", str(folder / "hyb.obj")]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith(f"wrote {folder / 'hyb.obj'}: hybrid blend of 2 meshes")
    assert captured.out.count("\n") == 1
    stages = ("read", "tetrahedralise", "decompose", "solve", "hybrid", "write")
    assert all(f"{stage}: 100%" in captured.err for stage in stages), captured.err
    assert re.search(r"decompose: 100%\|[^|\r\n]*\| 2/2 ", captured.err)  # one step per source mesh
    np.testing.assert_array_equal(read_mesh(folder / "hyb.obj").faces, F)


def test_blend_errors_are_clear(arms, tmp_path, capsys):
    folder, V0, _, F = arms
    other = tmp_path / "other.obj"
    write_obj(other, V0[:-8], F[np.all(F < len(V0) - 8, axis=1)])
    cases = [
        ([str(folder / "straight.obj"), str(other), "--weights", "1", "1"], "vertices"),
        ([str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1"], "need 2 weights"),
        ([str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1", "-1"], "non-negative"),
        ([str(folder / "straight.obj"), str(tmp_path / "missing.obj"), "--weights", "1", "1"], "missing.obj"),
    ]
    for args, message in cases:
        assert main(["blend", *args, "--out", str(tmp_path / "x.obj")]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "x.obj").exists()
    # the same vertices with other faces: both files and both face counts named, as build names them
    fewer, turned = tmp_path / "fewer.obj", tmp_path / "turned.obj"
    write_obj(fewer, V0, F[:-2])
    write_obj(turned, V0, np.vstack([F[:5], F[5, [1, 2, 0]], F[6:]]))
    straight = folder / "straight.obj"
    for mesh, message in ((fewer, f"{fewer} has {len(F) - 2} faces, {straight} has {len(F)}; blending needs meshes "
                                  "with the same topology (the face count differs)"),
                          (turned, f"{turned}: face 5 is {tuple(F[5, [1, 2, 0]].tolist())} but in {straight} it is "
                                   f"{tuple(F[5].tolist())}; blending needs meshes with the same topology "
                                   "(the connectivity differs)")):
        assert main(["blend", str(straight), str(mesh), "--weights", "1", "1", "--out", str(tmp_path / "x.obj")]) == 2
        assert message in capsys.readouterr().err


def test_open_surfaces_blend_non_linearly_and_a_flat_one_is_explained(tmp_path, capsys):
    box = trimesh.creation.box(extents=(1, 1, 1)).subdivide().subdivide()
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    F = F[V[F].mean(axis=1)[:, 1] < 0.45]  # a box missing its top: holes are capped for the tets
    write_obj(tmp_path / "a.obj", V, F)
    write_obj(tmp_path / "b.obj", V * 1.1, F)
    assert main(["blend", str(tmp_path / "a.obj"), str(tmp_path / "b.obj"), "--weights", "1", "1",
                 "--mode", "linear", "--out", str(tmp_path / "lin.obj")]) == 0
    np.testing.assert_allclose(read_mesh(tmp_path / "lin.obj").vertices, 1.05 * V, atol=1e-9)
    assert main(["blend", str(tmp_path / "a.obj"), str(tmp_path / "b.obj"), "--weights", "1", "1",
                 "--mode", "nonlinear", "--out", str(tmp_path / "nl.obj")]) == 0
    half = read_mesh(tmp_path / "nl.obj").vertices
    # blending a uniform scale's stretch gives the halfway scale, up to where the solve anchors it
    np.testing.assert_allclose(half - half.mean(axis=0), 1.05 * (V - V.mean(axis=0)), atol=0.01)
    flat = V * [1.0, 0.0, 1.0]
    write_obj(tmp_path / "flat.obj", flat, F)
    assert main(["blend", str(tmp_path / "flat.obj"), str(tmp_path / "b.obj"), "--weights", "1", "1",
                 "--mode", "nonlinear", "--out", str(tmp_path / "nl2.obj")]) == 2
    err = capsys.readouterr().err
    assert "flat.obj" in err and "encloses no lattice cell" in err


def test_a_surface_with_a_floating_piece_blends_non_linearly(arms, tmp_path):
    """A reconstruction fragment (a closed blob beside the arm, turning and moving on its own)
    fills as a solid part of its own: the blend keeps both parts' volumes, and the blob lands
    where the linear blend puts it."""
    folder, V0, V1, F = arms
    blob = trimesh.creation.icosphere(subdivisions=2, radius=0.06)
    B0, BF = np.asarray(blob.vertices) * [1.5, 1.0, 1.0] + [0.3, 0.1, 0.0], np.asarray(blob.faces)
    c, s = np.cos(np.radians(80)), np.sin(np.radians(80))
    B1 = (B0 - B0.mean(axis=0)) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + B0.mean(axis=0) + [0.05, 0.1, 0.0]
    F2 = np.vstack([F, BF + len(V0)])
    write_obj(tmp_path / "a.obj", np.vstack([V0, B0]), F2)
    write_obj(tmp_path / "b.obj", np.vstack([V1, B1]), F2)
    for mode in ("nonlinear", "hybrid"):
        out = tmp_path / f"{mode}.obj"
        assert main(["blend", str(tmp_path / "a.obj"), str(tmp_path / "b.obj"), "--weights", "1", "1",
                     "--mode", mode, "--out", str(out)]) == 0
        half = read_mesh(out).vertices
        piece = half[len(V0):]
        np.testing.assert_allclose(piece.mean(axis=0), 0.5 * (B0 + B1).mean(axis=0), atol=2e-3)
        assert enclosed_volume(piece, BF) == pytest.approx(enclosed_volume(B0, BF), rel=0.03)
        assert enclosed_volume(0.5 * (B0 + B1), BF) < 0.9 * enclosed_volume(B0, BF)  # linear squeezes it
        assert enclosed_volume(half[:len(V0)], F) == pytest.approx(enclosed_volume(V0, F), rel=0.03)


def test_meshes_in_millimetres_z_up_blend_as_in_metres_and_come_back_in_their_units(arms, tmp_path, capsys):
    """--units/--up (or detection) put the meshes in metres, +Y up for the blend; the output is
    written in the inputs' units and axes, and equals the metres blend converted."""
    folder, V0, V1, F = arms
    from engine.mesh_io.units import from_metres_y_up

    write_obj(tmp_path / "a.obj", from_metres_y_up(V0, "mm", "z"), F)
    write_obj(tmp_path / "b.obj", from_metres_y_up(V1, "mm", "z"), F)
    metres = tmp_path / "metres.obj"
    assert main(["blend", str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1", "1",
                 "--mode", "nonlinear", "--out", str(metres)]) == 0
    capsys.readouterr()
    for options in ([], ["--units", "mm", "--up", "z"]):
        out = tmp_path / f"mm{len(options)}.obj"
        assert main(["blend", str(tmp_path / "a.obj"), str(tmp_path / "b.obj"), "--weights", "1", "1",
                     "--mode", "nonlinear", "--compare", "--out", str(out), *options]) == 0
        captured = capsys.readouterr()
        assert "units mm (" + ("given" if options else "detected") in captured.err and "up +Z" in captured.err
        assert "in the inputs' units (mm, up +Z)" in captured.out and " mm (" in captured.out
        np.testing.assert_allclose(read_mesh(out).vertices, from_metres_y_up(read_mesh(metres).vertices, "mm", "z"),
                                   atol=2e-3)  # mm: 2 um


def test_vertex_colours_are_mixed_by_the_weights(arms, tmp_path):
    """Inputs with vertex colours give a blend with their colours mixed by the weights (a docs-only
    trial found them dropped); one input without colours gives none."""
    folder, V0, V1, F = arms
    red, blue = np.tile([1.0, 0.0, 0.0], (len(V0), 1)), np.tile([0.0, 0.0, 1.0], (len(V0), 1))
    write_ply(tmp_path / "a.ply", V0, F, colors=red)
    write_obj(tmp_path / "b.obj", V1, F, colors=blue)
    assert main(["blend", str(tmp_path / "a.ply"), str(tmp_path / "b.obj"), "--weights", "3", "1",
                 "--mode", "linear", "--out", str(tmp_path / "mix.ply")]) == 0
    np.testing.assert_allclose(read_mesh(tmp_path / "mix.ply").colors, np.tile([0.75, 0.0, 0.25], (len(V0), 1)),
                               atol=1 / 255)
    assert main(["blend", str(tmp_path / "a.ply"), str(folder / "bent.ply"), "--weights", "1", "1",
                 "--mode", "linear", "--out", str(tmp_path / "plain.ply")]) == 0
    assert read_mesh(tmp_path / "plain.ply").colors is None


def test_bad_weights_epsilon_outputs_and_units_are_named(arms, tmp_path, capsys):
    folder, V0, V1, F = arms
    inputs = [str(folder / "straight.obj"), str(folder / "bent.ply")]
    out = tmp_path / "o.obj"
    # huge weights blend as their ratio (their sum overflowed: every vertex came out at the origin)
    assert main(["blend", *inputs, "--weights", "1e308", "1e308", "--mode", "linear", "--out", str(out)]) == 0
    np.testing.assert_allclose(read_mesh(out).vertices, 0.5 * (V0 + V1), atol=1e-5)
    capsys.readouterr()
    for eps in ("nan", "inf", "0", "100.5"):  # (above 0 and at most 100, as build's)
        assert main(["blend", *inputs, "--weights", "1", "1", "--mode", "hybrid", "--epsilon-mm", eps,
                     "--out", str(out)]) == 2
        assert "--epsilon-mm must be above 0 and at most 100 (mm)" in capsys.readouterr().err
    assert main(["blend", *inputs, "--weights", "1", "1", "--out", str(tmp_path)]) == 2
    assert "is a directory: name the output mesh file" in capsys.readouterr().err
    # an output type that cannot be written is named before the meshes are read (no progress shown)
    assert main(["blend", *inputs, "--weights", "1", "1", "--out", str(tmp_path / "o.txt")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("morphspace blend: error: --out ") and "cannot write this file type (writable: .obj" in err
    write_obj(tmp_path / "mm.obj", 1000.0 * V1, F)  # the same arm in millimetres
    out = tmp_path / "o2.obj"  # (o.obj exists now: replacing it needs --force)
    assert main(["blend", inputs[0], str(tmp_path / "mm.obj"), "--weights", "1", "1", "--out", str(out)]) == 2
    assert re.search(r"mm\.obj is \d+ times the size of .*straight\.obj: blend meshes in the same units",
                     capsys.readouterr().err)
    write_obj(tmp_path / "point.obj", np.zeros_like(V0), F)
    assert main(["blend", inputs[0], str(tmp_path / "point.obj"), "--weights", "1", "1", "--out", str(out)]) == 2
    assert "point.obj: model size must be positive" in capsys.readouterr().err


def test_blend_refuses_an_existing_output_without_force_and_never_replaces_an_input(arms, capsys):
    """(It replaced an existing file, even one of its own inputs, without a word; a docs-only user.)"""
    folder, V0, _, F = arms
    inputs = [str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1", "1", "--mode", "linear"]
    before = (folder / "straight.obj").read_bytes()
    assert main(["blend", *inputs, "--out", str(folder / "straight.obj"), "--force"]) == 2
    assert "is one of the input meshes" in capsys.readouterr().err
    assert (folder / "straight.obj").read_bytes() == before
    out = folder / "again.obj"
    assert main(["blend", *inputs, "--out", str(out)]) == 0
    written = out.read_bytes()
    assert main(["blend", *inputs[:4], "3", "--mode", "linear", "--out", str(out)]) == 2
    assert "exists; pass --force to replace it" in capsys.readouterr().err and out.read_bytes() == written
    assert main(["blend", *inputs[:4], "3", "--mode", "linear", "--out", str(out), "--force"]) == 0
    assert out.read_bytes() != written


def test_stray_points_no_face_uses_change_nothing_of_the_surface(arms, tmp_path, capsys):
    """Scans keep vertices no face uses. They were the blend's units, size and solid: three of them
    30-50 m away made it refuse the mesh as "too thin", 500 beside the body bent the surface by up
    to 0.6 m. Now the surface blends as without them, and they are written where the weights' mean
    puts them (the files' own vertex numbering kept)."""
    folder, V0, V1, F = arms
    rng = np.random.default_rng(5)
    for name, count, spread in (("far", 3, 40.0), ("near", 200, 0.3)):
        stray0 = rng.normal(0.0, spread, (count, 3))
        stray1 = stray0 + rng.normal(0.0, 0.05, (count, 3))
        # the strays first: every face renumbered past them
        write_obj(tmp_path / f"a_{name}.obj", np.vstack([stray0, V0]), F + count)
        write_obj(tmp_path / f"b_{name}.obj", np.vstack([stray1, V1]), F + count)
        for mode in ("nonlinear", "hybrid"):
            clean, out = tmp_path / f"clean_{mode}.obj", tmp_path / f"{name}_{mode}.obj"
            if not clean.exists():
                assert main(["blend", str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1", "3",
                             "--mode", mode, "--out", str(clean)]) == 0
            assert main(["blend", str(tmp_path / f"a_{name}.obj"), str(tmp_path / f"b_{name}.obj"), "--weights", "1",
                         "3", "--mode", mode, "--out", str(out)]) == 0
            assert f"{count} vertices that no face uses are left out of the blend" in capsys.readouterr().err
            written = read_mesh(out)
            np.testing.assert_array_equal(written.faces, F + count)
            np.testing.assert_allclose(written.vertices[count:], read_mesh(clean).vertices, rtol=0, atol=1e-6)
            np.testing.assert_allclose(written.vertices[:count], 0.25 * stray0 + 0.75 * stray1, rtol=0, atol=1e-5)


def test_meshes_far_from_their_origin_keep_their_millimetres(arms, tmp_path):
    """Survey coordinates: the same arms 1,000 km from the origin blend as at the origin, moved
    (they were cast to float32 before their centre was taken out: 66 mm off)."""
    folder, V0, V1, F = arms
    offset = np.array([1.0e6, 0.0, 2.0e6])
    write_ply(tmp_path / "a.ply", V0 + offset, F, dtype=np.float64)
    write_ply(tmp_path / "b.ply", V1 + offset, F, dtype=np.float64)
    for mode in ("nonlinear", "hybrid"):
        near, far = tmp_path / f"near_{mode}.ply", tmp_path / f"far_{mode}.ply"
        assert main(["blend", str(folder / "straight.obj"), str(folder / "bent.ply"), "--weights", "1", "1",
                     "--mode", mode, "--units", "m", "--out", str(near)]) == 0
        assert main(["blend", str(tmp_path / "a.ply"), str(tmp_path / "b.ply"), "--weights", "1", "1",
                     "--mode", mode, "--units", "m", "--out", str(far)]) == 0
        np.testing.assert_allclose(read_mesh(far).vertices - offset, read_mesh(near).vertices, rtol=0, atol=1e-4)

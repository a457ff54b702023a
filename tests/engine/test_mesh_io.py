"""Tests for engine.mesh_io: mesh files, sequences, validation and npz storage."""

from __future__ import annotations

import dataclasses
import io
import os
import re
import zipfile

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine.mesh_io import (
    Mesh,
    MeshError,
    MeshFormatError,
    MeshSequence,
    MeshSequenceError,
    MeshValidationError,
    fan_triangulate,
    list_frames,
    load_sequence_npz,
    natural_key,
    read_frames,
    read_mesh,
    read_sequence,
    save_sequence_npz,
    validate_mesh,
    write_frames,
    write_obj,
    write_off,
    write_ply,
    write_sequence,
)

# --------------------------------------------------------------------------------------------
# Fixtures built in code


def unit_cube_quads():
    """Unit cube as 8 vertices (index 4x + 2y + z) and 6 outward-oriented quads."""
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    Q = np.array(
        [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    )
    return V, Q


def regular_hexagon():
    """Regular hexagon of circumradius 1 in the XZ plane: 6 vertices, one 6-gon."""
    angles = np.arange(6) * np.pi / 3
    V = np.stack([np.cos(angles), np.zeros(6), np.sin(angles)], axis=1)
    return V, np.arange(6)[None, :]


def total_area(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()


def signed_volume(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0


def polygon_obj(V, polygons):
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in V.tolist()]
    lines += ["f " + " ".join(str(i + 1) for i in p) for p in polygons]
    return ("\n".join(lines) + "\n").encode()


def polygon_off(V, polygons):
    lines = ["OFF", f"{len(V)} {len(polygons)} 0"]
    lines += [f"{x!r} {y!r} {z!r}" for x, y, z in V.tolist()]
    lines += [f"{len(p)} " + " ".join(str(i) for i in p) for p in polygons]
    return ("\n".join(lines) + "\n").encode()


def polygon_ply(V, polygons, binary, byte_order="<"):
    """PLY with double vertices and `list uchar uint` faces of any sizes."""
    fmt = "ascii"
    if binary:
        fmt = {"<": "binary_little_endian", ">": "binary_big_endian"}[byte_order]
    header = (
        f"ply\nformat {fmt} 1.0\ncomment test\nelement vertex {len(V)}\n"
        "property double x\nproperty double y\nproperty double z\n"
        f"element face {len(polygons)}\nproperty list uchar uint vertex_indices\nend_header\n"
    ).encode()
    if not binary:
        body = "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
        body += "".join(f"{len(p)} " + " ".join(map(str, p)) + "\n" for p in polygons)
        return header + body.encode()
    body = np.asarray(V, dtype=f"{byte_order}f8").tobytes()
    for p in polygons:
        body += bytes([len(p)]) + np.asarray(p, dtype=f"{byte_order}u4").tobytes()
    return header + body


def tetrahedron():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return V, F


def random_mesh(seed, n=30, m=40):
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(n, 3))
    F = rng.integers(0, n, size=(m, 3))
    colors = rng.random((n, 3)).astype(np.float32)
    return V, F, colors


# --------------------------------------------------------------------------------------------
# Round trips


def test_obj_round_trip_is_bit_exact(tmp_path):
    V, F, colors = random_mesh(0)
    path = tmp_path / "mesh.obj"
    assert write_obj(path, V, F, colors) == path
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.vertices, V)
    np.testing.assert_array_equal(mesh.faces, F)
    np.testing.assert_array_equal(mesh.colors, colors)
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64
    assert mesh.colors.dtype == np.float32
    assert mesh.source == str(path)


@pytest.mark.parametrize("binary", [True, False])
def test_ply_round_trip_float32_default_and_float64_option(tmp_path, binary):
    V, F, colors = random_mesh(1)
    path = tmp_path / "mesh.ply"
    write_ply(path, V, F, colors, binary=binary)
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.vertices, V.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(mesh.faces, F)
    np.testing.assert_allclose(mesh.colors, colors, atol=0.5 / 255 + 1e-7)
    write_ply(path, V, F, binary=binary, dtype=np.float64)
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.vertices, V)
    assert mesh.colors is None


def test_off_and_coff_round_trip(tmp_path):
    V, F, colors = random_mesh(2)
    write_off(tmp_path / "plain.off", V, F)
    mesh = read_mesh(tmp_path / "plain.off")
    np.testing.assert_array_equal(mesh.vertices, V)
    np.testing.assert_array_equal(mesh.faces, F)
    assert mesh.colors is None
    write_off(tmp_path / "colour.off", V, F, colors)
    assert (tmp_path / "colour.off").read_bytes().startswith(b"COFF\n")
    mesh = read_mesh(tmp_path / "colour.off")
    np.testing.assert_allclose(mesh.colors, colors, atol=0.5 / 255 + 1e-7)


def test_glb_written_by_trimesh_reads_back_with_colours(tmp_path):
    V, F, colors = random_mesh(3)
    rgba = np.hstack([np.round(colors * 255), np.full((len(V), 1), 255)]).astype(np.uint8)
    source = trimesh.Trimesh(V, F, vertex_colors=rgba, process=False)
    path = tmp_path / "mesh.glb"
    path.write_bytes(source.export(file_type="glb"))
    mesh = read_mesh(path)
    np.testing.assert_allclose(mesh.vertices, V, atol=1e-6 * np.abs(V).max())
    np.testing.assert_array_equal(mesh.faces, F)
    np.testing.assert_allclose(mesh.colors, rgba[:, :3] / 255.0, atol=1e-6)


def test_glb_applies_node_transforms_and_mirrors_keep_outward_winding():
    V, F = tetrahedron()
    scene = trimesh.Scene()
    shifted = np.eye(4)
    shifted[:3, 3] = [10.0, 0.0, 0.0]
    mirrored = np.diag([-1.0, 1.0, 1.0, 1.0])
    scene.add_geometry(trimesh.Trimesh(V, F, process=False), node_name="a", transform=shifted)
    scene.add_geometry(trimesh.Trimesh(V, F, process=False), node_name="b", transform=mirrored)
    mesh = read_mesh(scene.export(file_type="glb"), name="two.glb")
    assert mesh.vertices.shape == (8, 3) and mesh.faces.shape == (8, 3)
    positions = {tuple(np.round(p, 6)) for p in mesh.vertices.tolist()}
    assert {(10.0, 0.0, 0.0), (11.0, 0.0, 0.0), (-1.0, 0.0, 0.0)} <= positions
    # each instance is a closed tetrahedron of volume 1/6 with outward normals
    for part in (mesh.faces[:4], mesh.faces[4:]):
        assert signed_volume(mesh.vertices, part) == pytest.approx(1 / 6)


def test_our_obj_is_read_identically_by_trimesh(tmp_path):
    V, F, _ = random_mesh(4)
    path = tmp_path / "check.obj"
    write_obj(path, V, F)
    other = trimesh.load(path, process=False)
    np.testing.assert_array_equal(np.asarray(other.vertices), V)
    np.testing.assert_array_equal(np.asarray(other.faces), F)


def test_trimesh_ply_is_read_by_us(tmp_path):
    V, F, _ = random_mesh(5)
    path = tmp_path / "by_trimesh.ply"
    path.write_bytes(trimesh.Trimesh(V, F, process=False).export(file_type="ply"))
    mesh = read_mesh(path)
    np.testing.assert_allclose(mesh.vertices, V, rtol=1e-6)
    np.testing.assert_array_equal(mesh.faces, F)


mesh_strategy = st.integers(min_value=3, max_value=40).flatmap(
    lambda n: st.tuples(
        st.lists(
            st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False, width=64)] * 3),
            min_size=n,
            max_size=n,
        ),
        st.lists(st.tuples(*[st.integers(0, n - 1)] * 3), min_size=1, max_size=60),
    )
)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(mesh_strategy)
def test_random_meshes_round_trip_through_obj_and_ply(tmp_path, mesh):
    V, F = np.array(mesh[0], dtype=float), np.array(mesh[1], dtype=np.int64)
    write_obj(tmp_path / "m.obj", V, F)
    write_ply(tmp_path / "m.ply", V, F, dtype=np.float64)
    write_ply(tmp_path / "m32.ply", V, F, binary=False)
    for name, expected in [
        ("m.obj", V),
        ("m.ply", V),
        ("m32.ply", V.astype(np.float32).astype(np.float64)),
    ]:
        back = read_mesh(tmp_path / name)
        np.testing.assert_array_equal(back.vertices, expected)
        np.testing.assert_array_equal(back.faces, F)


# --------------------------------------------------------------------------------------------
# Polygons and OBJ details


@pytest.mark.parametrize(
    "kind",
    ["obj", "off", "ply_ascii", "ply_binary_le", "ply_binary_be", "ply_mixed", "ply_mixed_ascii"],
)
def test_cube_of_quads_becomes_12_triangles_of_total_area_6(kind):
    V, Q = unit_cube_quads()
    polygons = [list(q) for q in Q]
    if kind.startswith("ply_mixed"):  # variable-length lists: one quad split by hand
        polygons = polygons[:-1] + [[1, 5, 7], [1, 7, 3]]
    data = {
        "obj": lambda: polygon_obj(V, polygons),
        "off": lambda: polygon_off(V, polygons),
        "ply_ascii": lambda: polygon_ply(V, polygons, binary=False),
        "ply_binary_le": lambda: polygon_ply(V, polygons, binary=True),
        "ply_binary_be": lambda: polygon_ply(V, polygons, binary=True, byte_order=">"),
        "ply_mixed": lambda: polygon_ply(V, polygons, binary=True),
        "ply_mixed_ascii": lambda: polygon_ply(V, polygons, binary=False),
    }[kind]()
    extension = kind.split("_")[0]
    mesh = read_mesh(data, name=f"cube.{extension}")
    assert mesh.faces.shape == (12, 3)
    assert total_area(mesh.vertices, mesh.faces) == pytest.approx(6.0)
    assert signed_volume(mesh.vertices, mesh.faces) == pytest.approx(1.0)


def test_hexagon_fan_gives_4_triangles_with_the_hexagon_area():
    V, P = regular_hexagon()
    mesh = read_mesh(polygon_obj(V, P), name="hexagon.obj")
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]])
    assert total_area(mesh.vertices, mesh.faces) == pytest.approx(3 * np.sqrt(3) / 2)


def test_fan_triangulate_mixed_sizes_keeps_polygon_order():
    F = fan_triangulate(np.arange(12), [3, 4, 5])
    np.testing.assert_array_equal(
        F, [[0, 1, 2], [3, 4, 5], [3, 5, 6], [7, 8, 9], [7, 9, 10], [7, 10, 11]]
    )


def test_obj_corner_forms_and_negative_indices_agree():
    vertices = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
    forms = [
        "f 1 2 3 4",
        "f 1/1 2/2 3/3 4/4",
        "f 1//1 2//2 3//3 4//4",
        "f 1/1/1 2/2/2 3/3/3 4/4/4",
        "f -4 -3 -2 -1",
        "f -4/1/1 -3//2 -2/3 -1",
    ]
    for form in forms:
        mesh = read_mesh((vertices + form + "\n").encode(), name="quad.obj")
        np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]], err_msg=form)


def test_obj_trailing_comments_are_ignored():
    text = b"v 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 2 3 # the only face\n"
    mesh = read_mesh(text, name="comments.obj")
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])


def test_obj_negative_indices_are_relative_to_the_latest_vertex():
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 0 0\nv 6 0 0\nv 5 1 0\nf -3 -2 -1\n"
    mesh = read_mesh(text.encode(), name="relative.obj")
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [3, 4, 5]])


def test_obj_ignores_other_statements_and_reads_w_and_0_255_colours():
    text = b"""# exported by hand
mtllib scene.mtl
o body
g torso
s 1
  v 0 0 0 1.0
v 1 0 0 1.0
v\t0 1 0 1.0
vt 0.5 0.5
vn 0 0 1
usemtl skin
f 1/1/1 2/1/1 \\
  3/1/1
l 1 2
"""
    mesh = read_mesh(text, name="extras.obj")
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])
    assert mesh.colors is None
    text = b"v 0 0 0 255 0 0\nv 1 0 0 0 255 0\nv 0 1 0 0 0 51\nf 1 2 3\n"
    coloured = read_mesh(text, name="c.obj")
    np.testing.assert_allclose(coloured.colors, [[1, 0, 0], [0, 1, 0], [0, 0, 0.2]], atol=1e-7)


def _float_colour_ply(rows):
    header = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "property float red\nproperty float green\nproperty float blue\nelement face 1\n"
              "property list uchar int vertex_indices\nend_header\n")
    corners = ("0 0 0", "1 0 0", "0 1 0")
    return (header + "".join(f"{p} {r} {g} {b}\n" for p, (r, g, b) in zip(corners, rows)) + "3 0 1 2\n").encode()


def test_ply_float_colours_in_0_255_are_read_as_obj_and_coff_colours_are():
    """A float red of 200 was refused ("colours must be within [0, 1]") where OBJ and COFF read 0-255."""
    mesh = read_mesh(_float_colour_ply([(200, 100, 51), (0, 255, 0), (0, 0, 0)]), name="f.ply")
    np.testing.assert_allclose(mesh.colors, [[200 / 255, 100 / 255, 0.2], [0, 1, 0], [0, 0, 0]], atol=1e-6)
    unit = read_mesh(_float_colour_ply([(0.5, 0.25, 1), (0, 1, 0), (0, 0, 0)]), name="u.ply")
    np.testing.assert_allclose(unit.colors[0], [0.5, 0.25, 1.0])
    with pytest.raises(MeshFormatError, match=r"^n\.ply: vertex 1 has green -3: vertex colours must be within "
                                              r"\[0, 1\] or 0-255"):
        read_mesh(_float_colour_ply([(0.5, 0.25, 1), (0, -3, 0), (0, 0, 0)]), name="n.ply")
    with pytest.raises(MeshFormatError, match=r"^b\.ply: vertex 2 has blue 300"):
        read_mesh(_float_colour_ply([(0.5, 0.25, 1), (0, 1, 0), (0, 0, 300)]), name="b.ply")


def test_ply_extra_elements_and_properties_are_skipped():
    header = b"""ply
format binary_little_endian 1.0
element vertex 4
property float x
property float y
property float z
property float nx
property uchar red
property uchar green
property uchar blue
property uchar alpha
element material 1
property list ushort char name
element face 2
property uchar flags
property list int ushort vertex_index
end_header
"""
    vertices = np.zeros(4, dtype=[("xyz", "<f4", 3), ("nx", "<f4"), ("rgba", "u1", 4)])
    vertices["xyz"] = tetrahedron()[0]
    vertices["rgba"] = [[255, 0, 0, 9], [0, 255, 0, 9], [0, 0, 255, 9], [51, 102, 153, 9]]
    material = np.array([3], "<u2").tobytes() + b"abc"
    faces = b"".join(
        bytes([7]) + np.array([3], "<i4").tobytes() + np.array(f, "<u2").tobytes()
        for f in ([0, 2, 1], [0, 1, 3])
    )
    mesh = read_mesh(header + vertices.tobytes() + material + faces, name="extra.ply")
    np.testing.assert_array_equal(mesh.faces, [[0, 2, 1], [0, 1, 3]])
    np.testing.assert_allclose(mesh.colors[3], [0.2, 0.4, 0.6], atol=1e-7)


def test_read_mesh_accepts_bytes_file_objects_and_file_type_override(tmp_path):
    V, F = tetrahedron()
    path = tmp_path / "t.obj"
    write_obj(path, V, F)
    data = path.read_bytes()
    with open(path, "rb") as file:
        from_file = read_mesh(file)
    from_bytes = read_mesh(data, name="walk.zip:t.obj")
    renamed = tmp_path / "t.mesh"
    renamed.write_bytes(data)
    overridden = read_mesh(renamed, file_type=".OBJ")
    for mesh in (from_file, from_bytes, overridden):
        np.testing.assert_array_equal(mesh.faces, F)
    assert from_bytes.source == "walk.zip:t.obj"


def test_mesh_is_frozen_and_degenerate_faces_are_warnings_not_errors():
    V, F = tetrahedron()
    mesh = Mesh(V, np.vstack([F, [[0, 0, 1]]]), source="degenerate.obj")
    assert mesh.degenerate_faces.tolist() == [4]
    warnings = validate_mesh(mesh)
    assert len(warnings) == 1 and warnings[0].startswith("degenerate.obj: 1 degenerate face")
    assert validate_mesh(Mesh(V, F)) == []
    with pytest.raises(dataclasses.FrozenInstanceError):
        mesh.vertices = V


# --------------------------------------------------------------------------------------------
# Validation and format errors: right class, message starting with the file


def at(path):
    """Regex matching the start of a message about `path`."""
    return "^" + re.escape(str(path))


def write_bytes(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    return path


def test_non_finite_coordinate_names_the_file_and_vertex(tmp_path):
    path = write_bytes(tmp_path, "bad.obj", b"v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshValidationError) as error:
        read_mesh(path)
    assert str(error.value) == f"{path}: vertex 1 has a non-finite coordinate (nan)"
    ply = polygon_ply(np.array([[0, 0, 0], [1, 0, 0], [0, np.inf, 0]]), [[0, 1, 2]], binary=True)
    with pytest.raises(MeshValidationError, match=r"^x\.ply: vertex 2 .*\(inf\)"):
        read_mesh(ply, name="x.ply")


@pytest.mark.parametrize(
    "name, data, expected",
    [
        ("empty.obj", b"", "the file has 0 bytes"),
        ("empty.ply", b"", "the file has 0 bytes"),
        ("empty.off", b"", "the file has 0 bytes"),
        ("no_vertices.obj", b"# nothing\n", "0 vertices"),
        ("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "0 faces"),
        ("points.off", b"OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n", "0 faces"),
        ("points.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
         b"property float y\nproperty float z\nend_header\n0 0 0\n", "0 faces"),
    ],
)
def test_empty_meshes_are_rejected(tmp_path, name, data, expected):
    path = write_bytes(tmp_path, name, data)
    pattern = f"{at(path)}: the mesh is empty \\({expected}\\)"
    with pytest.raises(MeshValidationError, match=pattern):
        read_mesh(path)


def test_an_obj_cut_short_before_its_faces_says_so(tmp_path):
    V, F = tetrahedron()
    whole = polygon_obj(V, F.tolist())
    cut = write_bytes(tmp_path, "frame_3.obj", whole[:whole.index(b"\nf ") + 1])
    with pytest.raises(MeshValidationError, match=r"0 faces\): 4 vertices and no 'f' lines \(a point cloud, or a "
                                                  r"file cut short before its faces\)"):
        read_mesh(cut)


@pytest.mark.parametrize("tail, expected", [
    (b"f 1/1/1 2/2/2 3/3/3\nf 1/1/1 3/3/3 4/", r"ends in a corner '4/' unlike its others"),
    (b"f 1//1 2//2 3//3\nf 1//1 3//3 4/1", r"ends in a corner '4/1' unlike its others"),
    (b"f 1 2 3 4\nf 2 3 4 1\nf 3 4 1 2\nf 4 1 2 3\nf 1 2 3", r"has 3 corners where the 4 faces before it have 4"),
])
def test_an_obj_cut_inside_its_last_face_line_says_so(tmp_path, tail, expected):
    head = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n"
    path = write_bytes(tmp_path, "frame_7.obj", head + tail)
    line = head.count(b"\n") + tail.count(b"\n") + 1
    with pytest.raises(MeshFormatError, match=f"^{at(path)}: line {line}: the file does not end with a newline, and "
                                              f"its last face {expected}: a file cut short inside its last line"):
        read_mesh(path)


@pytest.mark.parametrize("tail", [
    b"f 1 2 3 4\nf 2 3 4 1\nf 3 4 1 2\nf 4 1 2 3\nf 1 2 3\n",  # a mixed mesh whose last line ends
    b"f 1 2 3 4\nf 2 3 4 1\nf 1 2 3",                          # too few faces before it to tell
    b"f 1 2 3\nf 1 3 4",                                        # a cut that would not show
    b"f 1/1 2/2 3/3\nf 1 3/3 4//2",                              # mixed forms: the line's others disagree
])
def test_an_obj_whose_last_face_only_could_be_cut_is_read(tmp_path, tail):
    head = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n"
    path = write_bytes(tmp_path, "frame_8.obj", head + tail)
    assert len(read_mesh(path).faces) >= 2


def test_face_index_out_of_range_names_face_and_index(tmp_path):
    V, F = tetrahedron()
    obj = write_bytes(tmp_path, "frame_12.obj", polygon_obj(V, [[0, 1, 2], [0, 1, 4]]))
    with pytest.raises(MeshValidationError) as error:
        read_mesh(obj)
    assert str(error.value) == (
        f"{obj}: face 1 (line 6) references vertex 5 but the file has 4 vertices"
    )
    with pytest.raises(MeshValidationError, match=r"references vertex -9, but only 4"):
        read_mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 -9\n", name="neg.obj")
    with pytest.raises(MeshValidationError, match=r"uses vertex index 0; OBJ indices start at 1"):
        read_mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", name="zero.obj")
    ply = polygon_ply(V, [[0, 1, 2], [0, 1, 2, 3], [3, 2, 4]], binary=True)
    with pytest.raises(MeshValidationError) as error:
        read_mesh(ply, name="walk/frame_12.ply")
    assert str(error.value) == (
        "walk/frame_12.ply: face 2 references vertex 4 but the mesh has 4 vertices"
    )
    with pytest.raises(MeshValidationError, match=r"^arr: face 0 references vertex -1"):
        Mesh(V, [[0, 1, -1]], source="arr")


def test_unsupported_extension_and_missing_file(tmp_path):
    path = write_bytes(tmp_path, "mesh.stl", b"solid x\nendsolid x\n")
    pattern = rf"{at(path)}: unsupported mesh file \(extension '\.stl'"
    with pytest.raises(MeshFormatError, match=pattern):
        read_mesh(path)
    with pytest.raises(MeshFormatError, match="needs a name or a file_type"):
        read_mesh(b"v 0 0 0")
    missing = tmp_path / "nope.obj"
    with pytest.raises(MeshFormatError, match=rf"{at(missing)}: cannot read the file"):
        read_mesh(missing)


@pytest.mark.parametrize("extension", ["obj", "ply", "off", "glb"])
def test_garbage_files_are_format_errors_naming_the_file(tmp_path, extension):
    garbage = bytes(np.random.default_rng(7).integers(0, 256, 2000, dtype=np.uint8))
    path = write_bytes(tmp_path, f"garbage.{extension}", garbage)
    with pytest.raises(MeshFormatError, match=f"{at(path)}: "):
        read_mesh(path)


@pytest.mark.parametrize(
    "name, data, pattern",
    [
        ("t.obj", b"hello world\nthis is text\n", "not an OBJ file"),
        ("t.obj", b"v 0 0 zero\nf 1 1 1\n", r"line 1: 'zero' is not a valid vertex coordinate"),
        ("t.obj", b"v 0 0 0\nv 0 0\n", "line 2: a vertex needs"),
        ("t.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "at least 3 vertices"),
        ("t.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "'x' is not a valid face"),
        ("t.off", b"OFF\n4 1\n0 0 0\n", "truncated"),
        ("t.off", b"NOFF\n", "unsupported OFF variant"),
        ("t.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n", "no 'x' property"),
        ("t.ply", b"ply\nformat binary_middle_endian 1.0\nend_header\n", "unsupported PLY format"),
        ("t.glb", b"glTF\x02\x00\x00\x00\xff\x00\x00\x00", "truncated"),
    ],
)
def test_parse_errors_are_precise(name, data, pattern):
    with pytest.raises(MeshFormatError, match=f"{at(name)}: .*{pattern}"):
        read_mesh(data, name=name)


def test_truncated_binary_ply_is_a_format_error(tmp_path):
    V, F, colors = random_mesh(8)
    path = tmp_path / "whole.ply"
    write_ply(path, V, F, colors)
    data = path.read_bytes()
    for cut in (len(data) - 1, len(data) - 40, len(data) // 2):
        with pytest.raises(MeshFormatError, match=r"^cut\.ply: truncated"):
            read_mesh(data[:cut], name="cut.ply")
    quads = polygon_ply(*unit_cube_quads(), binary=True)
    with pytest.raises(MeshFormatError, match=r"^q\.ply: truncated"):
        read_mesh(quads[:-3], name="q.ply")


# --------------------------------------------------------------------------------------------
# Sequences


def test_natural_key_orders_numbers_by_value_case_insensitively():
    names = ["frame_10.obj", "frame_9.obj", "Frame_2.OBJ", "frame_1.obj", "frame_100.obj"]
    assert sorted(names, key=natural_key) == [
        "frame_1.obj", "Frame_2.OBJ", "frame_9.obj", "frame_10.obj", "frame_100.obj",
    ]
    mixed = ["b2", "a10", "10", "a2", "2a", "a", "walk/f2.obj", "walk/f10.obj", "run/f3.obj"]
    assert sorted(mixed, key=natural_key) == [
        "2a", "10", "a", "a2", "a10", "b2", "run/f3.obj", "walk/f2.obj", "walk/f10.obj",
    ]
    assert sorted(["f01", "f1", "F1"], key=natural_key) == sorted(["f01", "f1", "F1"])


def test_stem_runs_group_consecutive_names_by_their_name_without_the_number():
    from engine.mesh_io.natural_sort import name_stem, stem_runs

    assert [name_stem(n) for n in ("take1/frame_0012.obj", "0012.ply", "f.001.OBJ", "walk")] == [
        "frame_", "", "f.", "walk"]
    assert stem_runs([]) == []
    assert stem_runs(["frame_1.ply", "Frame_2.PLY", "frame_10.obj"]) == [("frame_", 0, 2)]
    names = sorted(["frame_10.ply", "take_0004.ply", "frame_2.ply", "take_0005.ply", "0001.ply"], key=natural_key)
    assert stem_runs(names) == [("", 0, 0), ("frame_", 1, 2), ("take_", 3, 4)]


def make_sequence(frames=3, seed=0):
    V, F = tetrahedron()
    rng = np.random.default_rng(seed)
    return V[None] + 0.01 * rng.normal(size=(frames, *V.shape)), F


def test_directory_and_zip_of_the_same_frames_read_identically(tmp_path):
    vertices, F = make_sequence(frames=11)
    colors = np.random.default_rng(1).random(vertices.shape).astype(np.float32)
    directory = tmp_path / "walk"
    paths = write_sequence(directory, vertices, F, colors=colors)
    assert [p.name for p in paths] == [f"frame_{i:04d}.obj" for i in range(11)]
    (directory / "notes.txt").write_text("not a mesh")
    (directory / ".hidden.obj").write_text("garbage")
    (directory / "sub").mkdir()
    write_obj(directory / "sub" / "frame_0000.obj", vertices[0] + 5, F)  # not recursive
    archive = tmp_path / "walk.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in reversed(paths):  # member order must not matter
            zf.write(path, f"take1/{path.name}")
        zf.writestr("__MACOSX/take1/._frame_0000.obj", b"\x00\x05")
        zf.writestr("take1/.DS_Store", b"\x00")
        zf.writestr("take1/readme.md", b"hello")

    from_directory = read_sequence(directory)
    from_zip = read_sequence(archive)
    np.testing.assert_array_equal(from_directory.vertices, vertices)
    np.testing.assert_array_equal(from_zip.vertices, from_directory.vertices)
    np.testing.assert_array_equal(from_zip.faces, F)
    np.testing.assert_array_equal(from_zip.colors, colors)
    assert from_directory.names == [p.name for p in paths]
    assert from_zip.names == [f"take1/{p.name}" for p in paths]
    assert list_frames(archive) == from_zip.names
    assert from_zip.source == str(archive)
    assert len(from_zip) == 11 and from_zip.frame(3).source == "take1/frame_0003.obj"


def test_frames_sort_naturally_not_lexically(tmp_path):
    V, F = tetrahedron()
    for i in (10, 2, 1, 9):
        write_obj(tmp_path / f"frame_{i}.obj", V + i, F)
    assert list_frames(tmp_path) == ["frame_1.obj", "frame_2.obj", "frame_9.obj", "frame_10.obj"]
    sequence = read_sequence(tmp_path)
    np.testing.assert_array_equal(sequence.vertices[:, 0, 0], [1, 2, 9, 10])


def test_progress_is_called_after_each_frame(tmp_path):
    vertices, F = make_sequence(frames=3)
    calls = []
    write_sequence(tmp_path, vertices, F, format="ply", progress=lambda *a: calls.append(a))
    read_sequence(tmp_path, progress=lambda *a: calls.append(a))
    read_frames(tmp_path, progress=lambda *a: calls.append(a))
    assert calls == [(1, 3), (2, 3), (3, 3)] * 3


def test_unstructured_frames_keep_their_own_topology(tmp_path):
    V, F = tetrahedron()
    cube_V, cube_Q = unit_cube_quads()
    cube = read_mesh(polygon_obj(cube_V, cube_Q), name="cube.obj")
    paths = write_frames(tmp_path / "out", [(V, F), cube, (V * 2, F, np.full((4, 3), 0.5))])
    meshes = read_frames(tmp_path / "out")
    assert [len(m.vertices) for m in meshes] == [4, 8, 4]
    assert [m.source for m in meshes] == [str(p) for p in paths]
    np.testing.assert_array_equal(meshes[1].faces, cube.faces)
    assert meshes[2].colors is not None and meshes[0].colors is None


def test_differing_vertex_counts_name_both_files(tmp_path):
    V, F = tetrahedron()
    write_obj(tmp_path / "frame_0.obj", V, F)
    write_obj(tmp_path / "frame_1.obj", np.vstack([V, [[2, 2, 2]]]), F)
    with pytest.raises(MeshSequenceError) as error:
        read_sequence(tmp_path)
    first, second = tmp_path / "frame_0.obj", tmp_path / "frame_1.obj"
    assert str(error.value) == (
        f"{second} has 5 vertices, {first} has 4; consistent topology needs equal vertex counts"
    )
    assert len(read_frames(tmp_path)) == 2  # fine when topology is not required


def test_differing_faces_say_count_or_connectivity_and_which_face(tmp_path):
    V, F = tetrahedron()
    write_obj(tmp_path / "frame_0.obj", V, F)
    write_obj(tmp_path / "frame_1.obj", V, F[:3])
    with pytest.raises(MeshSequenceError, match=r"frame_1\.obj has 3 faces, .*frame_0\.obj has 4"):
        read_sequence(tmp_path)
    swapped = F.copy()
    swapped[2] = swapped[2, ::-1]
    write_obj(tmp_path / "frame_1.obj", V, swapped)
    with pytest.raises(MeshSequenceError) as error:
        read_sequence(tmp_path)
    assert str(error.value).startswith(f"{tmp_path / 'frame_1.obj'}: face 2 is (2, 3, 0) but in ")
    assert "connectivity" in str(error.value)


def test_sequence_container_errors(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(MeshSequenceError, match=rf"{at(empty)}: the directory is empty"):
        list_frames(empty)
    (empty / "notes.txt").write_text("x")
    with pytest.raises(MeshSequenceError, match=rf"{at(empty)}: no mesh files"):
        read_sequence(empty)
    with pytest.raises(MeshSequenceError, match="no such directory"):
        read_sequence(tmp_path / "missing")
    archive = tmp_path / "nomesh.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("a.txt", "x")
    with pytest.raises(MeshSequenceError, match=rf"{at(archive)}: no mesh files"):
        read_frames(archive)
    not_zip = write_bytes(tmp_path, "fake.zip", b"this is not a zip")
    with pytest.raises(MeshFormatError, match=rf"{at(not_zip)}: not a directory, and not a"):
        list_frames(not_zip)


def test_zip_member_over_the_size_limits_is_refused(tmp_path):
    vertices, F = make_sequence(frames=2)
    paths = write_sequence(tmp_path / "frames", vertices, F)
    archive = tmp_path / "frames.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in paths:
            zf.write(path, path.name)
    size = max(p.stat().st_size for p in paths)
    with pytest.raises(MeshFormatError) as error:
        read_sequence(archive, max_member_bytes=size - 1)
    assert str(error.value).startswith(f"{archive}:frame_000")
    assert "exceeds the limit" in str(error.value)
    with pytest.raises(MeshFormatError, match=rf"{at(archive)}: the mesh members add up to"):
        list_frames(archive, max_total_bytes=size)
    assert len(read_sequence(archive, max_member_bytes=size)) == 2


def test_zip_member_lying_about_its_size_is_refused(tmp_path):
    archive = tmp_path / "bomb.zip"
    payload = b"v 0 0 0\n" * 20000  # compresses to almost nothing
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("frame_0.obj", payload)
    data = bytearray(archive.read_bytes())
    # Rewrite the declared uncompressed size (local header and central directory) to 100 bytes.
    local = data.find(b"PK\x03\x04")
    central = data.find(b"PK\x01\x02")
    data[local + 22 : local + 26] = (100).to_bytes(4, "little")
    data[central + 24 : central + 28] = (100).to_bytes(4, "little")
    archive.write_bytes(bytes(data))
    with pytest.raises(MeshFormatError, match=rf"{at(archive)}:frame_0\.obj: "):
        read_sequence(archive, max_member_bytes=1000)


def test_write_sequence_refuses_to_mix_with_stale_frames(tmp_path):
    vertices, F = make_sequence(frames=3)
    write_sequence(tmp_path, vertices, F)
    write_sequence(tmp_path, vertices + 1, F)  # overwriting the same frames is fine
    with pytest.raises(MeshSequenceError, match="already holds 1 other mesh files"):
        write_sequence(tmp_path, vertices[:2], F)
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]  # no temporary files left


def test_writers_validate_and_leave_no_partial_file(tmp_path):
    V, F = tetrahedron()
    bad = V.copy()
    bad[2, 1] = np.nan
    for writer, name in [(write_obj, "a.obj"), (write_ply, "a.ply"), (write_off, "a.off")]:
        with pytest.raises(MeshValidationError, match=rf"{name}: vertex 2 has a non-finite"):
            writer(tmp_path / name, bad, F)
        with pytest.raises(MeshValidationError, match="face 0 references vertex 4"):
            writer(tmp_path / name, V, [[1, 2, 4]])
    assert os.listdir(tmp_path) == []


def test_mesh_errors_are_value_errors():
    assert issubclass(MeshError, ValueError)
    for cls in (MeshFormatError, MeshValidationError, MeshSequenceError):
        assert issubclass(cls, MeshError)


# --------------------------------------------------------------------------------------------
# npz storage


def test_npz_round_trip_with_colours_names_metadata_and_extra_arrays(tmp_path):
    vertices, F = make_sequence(frames=5)
    colors = np.random.default_rng(2).random(vertices.shape).astype(np.float32)
    rest = np.arange(12.0).reshape(4, 3)
    path = tmp_path / "walk.npz"
    names = [f"walk/f{i}.obj" for i in range(5)]
    save_sequence_npz(path, vertices, F, colors=colors, names=names, fps=30, actor="A", rest=rest)
    sequence = load_sequence_npz(path)
    np.testing.assert_array_equal(sequence.vertices, vertices.astype(np.float32))
    np.testing.assert_array_equal(sequence.faces, F)
    np.testing.assert_array_equal(sequence.colors, colors)
    np.testing.assert_array_equal(sequence.arrays["rest"], rest)
    assert sequence.names == names
    assert sequence.metadata == {"fps": 30, "actor": "A"}
    with np.load(path, allow_pickle=False) as raw:  # plain arrays, no pickle
        assert raw["vertices"].dtype == np.float32 and raw["faces"].dtype == np.int32
        assert raw["metadata"].dtype.kind == "U"


def test_npz_errors(tmp_path):
    vertices, F = make_sequence(frames=2)
    good = tmp_path / "good.npz"
    save_sequence_npz(good, vertices, F, compress=True)
    data = good.read_bytes()
    cases = {
        "text.npz": (b"just some text", "not an .npz file"),
        "truncated.npz": (data[: len(data) // 2], "truncated or corrupt"),
        "empty.npz": (b"", "not an .npz file"),
    }
    for name, (content, pattern) in cases.items():
        path = write_bytes(tmp_path, name, content)
        with pytest.raises(MeshFormatError, match=rf"{at(path)}: {pattern}"):
            load_sequence_npz(path)
    only_vertices = tmp_path / "partial.npz"
    np.savez(only_vertices, vertices=vertices)
    with pytest.raises(MeshFormatError, match=rf"{at(only_vertices)}: missing array 'faces'"):
        load_sequence_npz(only_vertices)
    flat = tmp_path / "flat.npz"
    np.savez(flat, vertices=vertices[0], faces=F)
    with pytest.raises(MeshFormatError, match=r"'vertices' must be a \(frames, n, 3\)"):
        load_sequence_npz(flat)
    npy = tmp_path / "single.npy"
    np.save(npy, vertices)
    with pytest.raises(MeshFormatError, match="single-array .npy file"):
        load_sequence_npz(npy)
    objects = tmp_path / "objects.npz"
    np.savez(objects, vertices=vertices, faces=F, metadata=np.array([{"a": 1}], dtype=object))
    with pytest.raises(MeshFormatError, match="unreadable array"):
        load_sequence_npz(objects)
    with pytest.raises(MeshFormatError, match="cannot read the file"):
        load_sequence_npz(tmp_path / "missing.npz")


def test_mesh_sequence_validates_its_arrays():
    vertices, F = make_sequence(frames=2)
    vertices[1, 3, 2] = np.inf
    with pytest.raises(MeshValidationError, match=r"^seq: frame 1 vertex 3 has a non-finite"):
        MeshSequence(vertices, F, source="seq")
    with pytest.raises(MeshValidationError, match=r"3 frame names for 2 frames"):
        MeshSequence(np.zeros((2, 4, 3)), F, names=["a", "b", "c"])
    assert MeshSequence(np.zeros((2, 4, 3)), F).names == ["frame_0000", "frame_0001"]


def test_large_obj_round_trips(tmp_path):
    rng = np.random.default_rng(9)
    V = rng.random((50_000, 3))
    F = rng.integers(0, len(V), size=(100_000, 3))
    path = tmp_path / "big.obj"
    write_obj(path, V, F)
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.faces, F)
    np.testing.assert_allclose(mesh.vertices, V, rtol=1e-8)


def test_reading_bytes_from_a_stream_object():
    V, F = tetrahedron()
    buffer = io.BytesIO(polygon_off(V, F))
    mesh = read_mesh(buffer, name="stream.off")
    np.testing.assert_array_equal(mesh.faces, F)


def test_obj_fixed_precision_rounds_coordinates(tmp_path):
    V, F = tetrahedron()
    V = V + 0.123456789
    path = tmp_path / "rounded.obj"
    write_obj(path, V, F, colors=np.full((len(V), 3), 0.5), precision=6)
    mesh = read_mesh(path)
    assert np.abs(mesh.vertices - V).max() <= 5e-7
    assert "0.123457" in path.read_text()
    np.testing.assert_allclose(mesh.colors, 0.5)


def test_left_out_frames_are_the_other_tools_formats_the_reader_skips(tmp_path):
    """Beside the frames: an .stl and an .fbx are named as left out; a .glb (read as a frame), a
    hidden file, a text file and a directory are not."""
    from engine.mesh_io.frames import left_out_frames

    for name in ("frame_1.obj", "frame_2.glb", "frame_10.STL", "frame_3.fbx", ".frame_4.stl", "notes.txt"):
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "more.stl").mkdir()
    assert left_out_frames(tmp_path) == ["frame_3.fbx", "frame_10.STL"]
    archive = tmp_path / "take.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for name in ("take/frame_1.ply", "take/frame_2.stl", "__MACOSX/take/frame_2.stl", "take/frame_3.glb"):
            zf.writestr(name, b"x")
    assert left_out_frames(archive) == ["take/frame_2.stl"]
    assert left_out_frames(tmp_path / "missing") == []


def test_ply_counts_the_file_cannot_hold_are_refused_before_reading(tmp_path):
    """A header declaring two billion faces made the reader allocate for them (MemoryError)."""
    for fmt in ("ascii", "binary_little_endian"):
        header = (f"ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 2000000000\nproperty list uchar int vertex_indices\nend_header\n").encode()
        body = b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n" if fmt == "ascii" else bytes(36) + bytes([3]) + bytes(12)
        with pytest.raises(MeshFormatError, match=r"^huge\.ply: truncated, or its counts are wrong: the header "
                                                  r"declares 3 vertex, 2000000000 face"):
            read_mesh(header + body, name="huge.ply")



def test_an_interrupt_at_any_line_of_an_atomic_write_leaves_no_temporary_file(tmp_path):
    """The target is absent or complete and no hidden temporary stays (the generator it replaced kept
    its temporary when the signal came just after the file was created: 5 signalled exports of 60).
    The one place left out is the first line of ``__exit__``, before its ``try`` (see ``AtomicFile``)."""
    import contextlib

    from engine.mesh_io.atomic import AtomicFile, atomic_write
    from interrupting import interrupt_at_every_line

    target = tmp_path / "out.bin"

    def write():
        target.unlink(missing_ok=True)
        with atomic_write(target) as file:
            file.write(b"complete")

    def check(at):
        names = sorted(p.name for p in tmp_path.iterdir())
        assert names in ([], ["out.bin"]), (at, names)
        assert not names or target.read_bytes() == b"complete"
        assert at is not None or names == ["out.bin"]

    exit_entry = (AtomicFile.__exit__.__code__, AtomicFile.__exit__.__code__.co_firstlineno + 1)
    lines = interrupt_at_every_line(write, [atomic_write.__code__.co_filename, contextlib.__file__], check,
                                    skip={exit_entry})
    assert lines > 10

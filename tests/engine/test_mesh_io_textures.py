"""Texture-mapped meshes (OBJ + MTL + image, PLY with texture coordinates, glTF): the texture is
baked into vertex colours when the mesh is read, from a directory or a zip archive of frames."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
import trimesh
from PIL import Image

from engine.mesh_io import MeshFormatError, MeshValidationError, read_frames, read_mesh
from engine.mesh_io.atlas import atlas, write_textured
from engine.mesh_io import texture
from engine.mesh_io.texture import MAX_TEXTURE_PIXELS, resource_name, sample_texture

QUAD_V = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
QUAD_VT = "vt 0.25 0.25\nvt 0.75 0.25\nvt 0.75 0.75\nvt 0.25 0.75\n"


def _png(path, rgb, size=(16, 16)):
    image = np.zeros((size[1], size[0], 3), np.uint8)
    image[:] = rgb
    Image.fromarray(image).save(path)


def _quadrants(path):
    """32 x 32: top-left red, top-right green, bottom-left blue, bottom-right white."""
    image = np.zeros((32, 32, 3), np.uint8)
    image[:16, :16] = [255, 0, 0]
    image[:16, 16:] = [0, 255, 0]
    image[16:, :16] = [0, 0, 255]
    image[16:, 16:] = [255, 255, 255]
    Image.fromarray(image).save(path)


def test_obj_texture_is_baked_per_vertex_the_right_way_up(tmp_path):
    _quadrants(tmp_path / "tex.png")
    (tmp_path / "quad.mtl").write_text("newmtl skin\nKd 0.5 0.5 0.5\nmap_Kd tex.png\n")
    # each vertex's texture coordinate in the middle of a quadrant: v up from the bottom edge
    (tmp_path / "quad.obj").write_text(
        "mtllib quad.mtl\n" + QUAD_V + QUAD_VT + "usemtl skin\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    mesh = read_mesh(tmp_path / "quad.obj")
    # every corner's samples stay within its quadrant: blue bottom-left (u, v = 0.25, 0.25, v up
    # from the bottom edge), white bottom-right, green top-right, red top-left; the image as it
    # is, not multiplied by Kd
    np.testing.assert_allclose(mesh.colors, [[0, 0, 1], [1, 1, 1], [0, 1, 0], [1, 0, 0]], atol=1e-6)


def test_a_uniform_texture_gives_its_colour_exactly_and_plain_materials_their_kd(tmp_path):
    _png(tmp_path / "paint.png", [51, 102, 204])
    (tmp_path / "m.mtl").write_text(
        "# two materials\nnewmtl painted\nmap_Kd -s 1 1 1 -o 0.1 0 0 -clamp on paint.png\n\nnewmtl plain\nKd 1 0 0\n")
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\n" + QUAD_V + "v 2 0 0\n" + QUAD_VT
        + "usemtl painted\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\nusemtl plain\nf 2 5 3\n")
    mesh = read_mesh(tmp_path / "m.obj")
    np.testing.assert_allclose(mesh.colors[0], [0.2, 0.4, 0.8], atol=1 / 255)
    np.testing.assert_allclose(mesh.colors[4], [1, 0, 0])
    # vertex 1 touches both: the faces' colours weighted by their areas (0.5 painted, 0.5 plain)
    np.testing.assert_allclose(mesh.colors[1], 0.5 * np.array([0.2, 0.4, 0.8]) + 0.5 * np.array([1, 0, 0]),
                               atol=1 / 255)


def test_vertex_colours_on_v_lines_win_over_materials(tmp_path):
    _png(tmp_path / "t.png", [0, 0, 0])
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 0 1 0 1 0 0\nvt 0 0\n"
                                    "usemtl a\nf 1/1 2/1 3/1\n")
    np.testing.assert_allclose(read_mesh(tmp_path / "m.obj").colors, [[1, 0, 0]] * 3)


def test_faces_without_a_material_leave_the_mesh_without_colours(tmp_path):
    _png(tmp_path / "t.png", [10, 20, 30])
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + QUAD_V + QUAD_VT + "f 1/1 2/2 3/3\nusemtl a\nf 1/1 3/3 4/4\n")
    assert read_mesh(tmp_path / "m.obj").colors is None


def test_relative_texture_indices_polygons_and_folders(tmp_path):
    (tmp_path / "maps").mkdir()
    _png(tmp_path / "maps" / "t.png", [0, 255, 0])
    (tmp_path / "maps" / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")   # relative to the MTL
    (tmp_path / "q.obj").write_text("mtllib maps/m.mtl\n" + QUAD_V + QUAD_VT + "usemtl a\nf 1/-4 2/-3 3/-2 4/-1\n")
    mesh = read_mesh(tmp_path / "q.obj")
    assert len(mesh.faces) == 2
    np.testing.assert_allclose(mesh.colors, [[0, 1, 0]] * 4, atol=1 / 255)


def test_missing_library_or_image_is_a_clear_error(tmp_path):
    (tmp_path / "m.obj").write_text("mtllib gone.mtl\n" + QUAD_V + QUAD_VT + "f 1/1 2/2 3/3\n")
    with pytest.raises(MeshFormatError, match=r"m\.obj: refers to 'gone\.mtl', which cannot be read beside it"):
        read_mesh(tmp_path / "m.obj")
    (tmp_path / "gone.mtl").write_text("newmtl a\nmap_Kd C:\\captures\\take 1\\frame.png\n")
    (tmp_path / "m.obj").write_text("mtllib gone.mtl\n" + QUAD_V + QUAD_VT + "usemtl a\nf 1/1 2/2 3/3\n")
    # an absolute path keeps its last part, looked for beside the mesh
    with pytest.raises(MeshFormatError, match=r"refers to 'frame\.png'"):
        read_mesh(tmp_path / "m.obj")
    (tmp_path / "frame.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(MeshFormatError, match=r"m\.obj: frame\.png: not a readable image \(UnidentifiedImageError\)$"):
        read_mesh(tmp_path / "m.obj")


def test_a_callers_resource_reader_may_fail_as_python_does(tmp_path):
    data = ("mtllib m.mtl\n" + QUAD_V + QUAD_VT + "usemtl a\nf 1/1 2/2 3/3\n").encode()

    def missing(name):
        raise FileNotFoundError(name)

    for reader, why in ((missing, "FileNotFoundError"), ({}.__getitem__, "KeyError"), (lambda name: None, "no data")):
        with pytest.raises(MeshFormatError, match=rf"m\.obj: refers to 'm\.mtl', which cannot be read \({why}"):
            read_mesh(data, name="m.obj", resources=reader)


def test_out_of_range_texture_coordinate_is_named(tmp_path):
    _png(tmp_path / "t.png", [0, 0, 0])
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + QUAD_V + "vt 0 0\nusemtl a\nf 1/1 2/1 3/7\n")
    with pytest.raises(MeshValidationError, match=r"face 0 \(line 8\) references texture coordinate 7, out of range \(the file has 1\)"):
        read_mesh(tmp_path / "m.obj")


def test_oversized_texture_is_refused_before_decoding(tmp_path):
    side = int(np.sqrt(MAX_TEXTURE_PIXELS)) + 1
    Image.new("1", (side, side)).save(tmp_path / "huge.png")
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd huge.png\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + QUAD_V + QUAD_VT + "usemtl a\nf 1/1 2/2 3/3\n")
    with pytest.raises(MeshFormatError, match=rf"huge\.png: the texture is {side} x {side} pixels"):
        read_mesh(tmp_path / "m.obj")


def test_bytes_without_resources_ignore_the_texture(tmp_path):
    data = ("mtllib m.mtl\n" + QUAD_V + QUAD_VT + "usemtl a\nf 1/1 2/2 3/3\n").encode()
    assert read_mesh(data, name="m.obj").colors is None


@pytest.mark.parametrize("kind", ["obj", "ply"])
def test_written_atlas_reads_back_as_the_vertex_colours(tmp_path, kind):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    V, F = sphere.vertices, sphere.faces
    colours = 0.5 + 0.5 * np.sin(3.0 * V)
    write_textured(tmp_path / f"ball.{kind}", V, F, colours)
    assert (tmp_path / "ball.png").exists() and (kind == "ply" or (tmp_path / "ball.mtl").exists())
    mesh = read_mesh(tmp_path / f"ball.{kind}")
    np.testing.assert_allclose(mesh.vertices, V, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, F)
    # smooth colours come back within a few levels (the bake averages a little around each corner)
    assert np.abs(mesh.colors - colours).max() < 0.02


def test_atlas_faces_never_read_their_neighbours_texels():
    # every face its own three vertices and its own flat colour: whatever the bake samples
    # within a face must be that colour (no texel of the neighbouring face in the cell, or of
    # the next cell, may leak in)
    rng = np.random.default_rng(0)
    m = 301
    F = np.arange(3 * m).reshape(-1, 3)
    face_colour = rng.integers(0, 256, (m, 3)) / 255.0
    image, corner_uv = atlas(F, np.repeat(face_colour, 3, axis=0))
    image = image.astype(np.float32) / 255.0
    weights = texture._CORNER_SAMPLES
    for corner in range(3):
        own, nxt, prv = (corner_uv[:, (corner + k) % 3] for k in (0, 1, 2))
        for w in weights:
            samples = sample_texture(image, w[0] * own + w[1] * nxt + w[2] * prv)
            np.testing.assert_allclose(samples, face_colour, atol=0.5 / 255)


def test_zip_frames_read_their_textures_from_the_archive(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=2)
    colours = np.tile([0.2, 0.6, 0.4], (len(sphere.vertices), 1))
    folder = tmp_path / "frames"
    for k in range(2):
        write_textured(folder / f"frame_{k}.obj", sphere.vertices, sphere.faces, colours)
    archive = tmp_path / "take.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for path in sorted(folder.iterdir()):
            z.write(path, f"take/{path.name}")
    frames = read_frames(archive)
    assert len(frames) == 2
    np.testing.assert_allclose(frames[1].colors, colours, atol=1 / 255)
    broken = tmp_path / "broken.zip"
    with zipfile.ZipFile(broken, "w") as z:
        z.write(folder / "frame_0.obj", "take/frame_0.obj")
        z.write(folder / "frame_0.mtl", "take/frame_0.mtl")
    with pytest.raises(MeshFormatError, match=r"broken\.zip:take/frame_0\.obj: refers to 'frame_0\.png', which is "
                                              r"not in the archive \(looked for member 'take/frame_0\.png'\)"):
        read_frames(broken)


def test_ply_with_per_vertex_texture_coordinates(tmp_path):
    _quadrants(tmp_path / "q.png")
    header = ("ply\nformat ascii 1.0\ncomment TextureFile q.png\nelement vertex 4\nproperty float x\n"
              "property float y\nproperty float z\nproperty float s\nproperty float t\nelement face 2\n"
              "property list uchar int vertex_indices\nend_header\n")
    body = "0 0 0 0.25 0.25\n1 0 0 0.75 0.25\n1 1 0 0.75 0.75\n0 1 0 0.25 0.75\n3 0 1 2\n3 0 2 3\n"
    (tmp_path / "q.ply").write_text(header + body)
    mesh = read_mesh(tmp_path / "q.ply")
    np.testing.assert_allclose(mesh.colors, [[0, 0, 1], [1, 1, 1], [0, 1, 0], [1, 0, 0]], atol=1e-6)
    (tmp_path / "q.png").unlink()
    with pytest.raises(MeshFormatError, match=r"q\.ply: refers to 'q\.png'"):
        read_mesh(tmp_path / "q.ply")


def test_glb_base_colour_texture_times_its_factor():
    image = np.zeros((8, 8, 3), np.uint8)
    image[:] = [200, 100, 50]
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    uv = np.array([[0.2, 0.2], [0.8, 0.2], [0.8, 0.8], [0.2, 0.8]])
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(image),
                                                   baseColorFactor=[255, 255, 127, 255])
    quad = trimesh.Trimesh(V, [[0, 1, 2], [0, 2, 3]], process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv, material=material))
    mesh = read_mesh(quad.export(file_type="glb"), name="quad.glb")
    np.testing.assert_allclose(mesh.colors, [[200 / 255, 100 / 255, 50 / 255 * 127 / 255]] * 4, atol=2 / 255)


def test_resource_names():
    assert resource_name("tex.png") == "tex.png"
    assert resource_name('"maps\\skin 1.jpg"') == "maps/skin 1.jpg"
    assert resource_name("/home/a/b.png") == "b.png"
    assert resource_name("D:\\x\\y.png") == "y.png"
    assert resource_name("../t.png", "maps") == "t.png"


def test_sample_texture_is_bilinear_and_repeats():
    image = np.zeros((2, 2, 3), np.float32)
    image[0, 0] = 1.0                      # top-left texel
    centre = sample_texture(image, np.array([[0.25, 0.75]]))
    np.testing.assert_allclose(centre, [[1, 1, 1]])
    np.testing.assert_allclose(sample_texture(image, np.array([[1.25, -0.25]])), centre)
    np.testing.assert_allclose(sample_texture(image, np.array([[0.5, 0.5]])), [[0.25] * 3])

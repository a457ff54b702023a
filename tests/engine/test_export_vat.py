"""Vertex-animation textures: a 16-bit PNG read back by an independent decoder, plus its mesh
(checked by the glTF Validator), give the player's frames within the texture's precision."""

import json
import struct
import zipfile
import zlib

import numpy as np
import pytest

from engine.export import Clip, play_clip, write_export
from engine.export.vat import MAX_WIDTH, vat_layout
from gltf_reader import Glb
from gltf_validator import assert_clean, validate


def read_png16(data):
    """(h, w, 3) uint16 of a 16-bit RGB PNG: chunks and CRCs checked, all five row filters undone."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    at, idat, header = 8, b"", None
    while at < len(data):
        (length,) = struct.unpack_from(">I", data, at)
        kind, body = data[at + 4:at + 8], data[at + 8:at + 8 + length]
        assert struct.unpack_from(">I", data, at + 8 + length)[0] == zlib.crc32(kind + body)
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        at += 12 + length
    width, height, depth, colour, _, _, interlace = header
    assert depth == 16 and colour == 2 and interlace == 0
    stride, bpp = width * 6, 6
    raw = zlib.decompress(idat)
    rows, previous = [], bytearray(stride)
    for y in range(height):
        kind, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for x in range(stride):
            a = line[x - bpp] if x >= bpp else 0
            b = previous[x]
            c = previous[x - bpp] if x >= bpp else 0
            if kind == 1:
                line[x] = (line[x] + a) & 255
            elif kind == 2:
                line[x] = (line[x] + b) & 255
            elif kind == 3:
                line[x] = (line[x] + (a + b) // 2) & 255
            elif kind == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[x] = (line[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
            else:
                assert kind == 0
        rows.append(bytes(line))
        previous = line
    return np.frombuffer(b"".join(rows), dtype=">u2").reshape(height, width, 3).astype(np.uint16)


@pytest.fixture(scope="module")
def walk(export_spaces):
    return play_clip(export_spaces["speed"], Clip(params={"speed": 1.0}, track=((0.5, {"speed": 2.5}),),
                                                  duration=1.5, rate=20))


@pytest.mark.parametrize("name", ["vat", "vat.zip"])
def test_texture_and_mesh_give_back_the_frames(walk, tmp_path, name):
    record = write_export(tmp_path / name, walk, "vat")
    if name.endswith(".zip"):
        with zipfile.ZipFile(tmp_path / name) as archive:
            files = {n: archive.read(n) for n in archive.namelist()}
    else:
        files = {p.name: p.read_bytes() for p in (tmp_path / name).iterdir()}
    assert sorted(files) == ["mesh.glb", "positions.png", "vat.json"]
    (tmp_path / "mesh.glb").write_bytes(files["mesh.glb"])
    assert_clean(validate(tmp_path / "mesh.glb"))
    meta = json.loads(files["vat.json"])
    n = walk.local.shape[1]
    assert (meta["width"], meta["rows_per_frame"], meta["height"], meta["frames"]) == (n, 1, len(walk), len(walk))
    assert 0 < meta["max_error_m"] < 2e-5 and record["max_error_m"] == meta["max_error_m"]
    image = read_png16(files["positions.png"])
    glb = Glb(files["mesh.glb"])
    primitive = glb.json["meshes"][0]["primitives"][0]
    base = glb.accessor(primitive["attributes"]["POSITION"])
    uv = glb.accessor(primitive["attributes"]["TEXCOORD_0"])
    column = np.floor(uv[:, 0] * meta["width"]).astype(int)
    row = np.floor(uv[:, 1] * meta["height"]).astype(int)
    assert np.array_equal(column, np.arange(n)) and np.all(row == 0)
    lo, hi = np.array(meta["minimum"]), np.array(meta["maximum"])
    for k in range(len(walk)):
        texels = image[row + k * meta["rows_per_frame"], column].astype(np.float64)
        local = base + lo + texels / 65535 * (hi - lo)
        assert np.abs(local - walk.local[k]).max() <= meta["max_error_m"] + 1e-6, k
        h = np.radians(meta["heading_deg"][k])
        R = np.array([[np.cos(h), 0, np.sin(h)], [0, 1, 0], [-np.sin(h), 0, np.cos(h)]])
        placed = local @ R.T + np.array(meta["root_position"][k])
        assert np.abs(placed - walk.world(k)).max() <= meta["max_error_m"] + 2e-6, k


def test_many_vertices_wrap_onto_more_rows():
    assert vat_layout(3000, 601) == (3000, 1, 601)
    assert vat_layout(20000, 10) == (MAX_WIDTH, 3, 30)
    with pytest.raises(ValueError, match="export a shorter clip or a lower rate"):
        vat_layout(20000, 20000)

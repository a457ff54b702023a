"""A small, independent GLB reader for the export tests: accessors (strided, normalized, sparse,
zero-filled) and the morph-target animation evaluated at its key times, as an engine would.

Written from the glTF 2.0 specification, not from the writer: it shares no code with
engine/export, so a test comparing its output with the player's checks the file itself.
"""

from __future__ import annotations

import json
import struct

import numpy as np

DTYPES = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


class Glb:
    def __init__(self, data):
        magic, version, length = struct.unpack_from("<4sII", data, 0)
        assert magic == b"glTF" and version == 2 and length == len(data), (magic, version, length, len(data))
        json_length, json_type = struct.unpack_from("<II", data, 12)
        assert json_type == 0x4E4F534A
        self.json = json.loads(data[20:20 + json_length])
        bin_at = 20 + json_length
        bin_length, bin_type = struct.unpack_from("<II", data, bin_at)
        assert bin_type == 0x004E4942
        self.bin = data[bin_at + 8:bin_at + 8 + bin_length]

    def _view_items(self, view_index, offset, count, dtype, width, stride=None):
        view = self.json["bufferViews"][view_index]
        start = view.get("byteOffset", 0) + offset
        item = np.dtype(dtype).itemsize * width
        stride = stride or view.get("byteStride") or item
        assert offset + stride * (count - 1) + item <= view["byteLength"], "accessor runs past its view"
        raw = np.frombuffer(self.bin, dtype=np.uint8, count=stride * (count - 1) + item, offset=start)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, item), strides=(stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def accessor(self, index):
        """(count, width) float64 values (normalized integers mapped to [-1, 1] / [0, 1])."""
        a = self.json["accessors"][index]
        dtype, width, count = DTYPES[a["componentType"]], WIDTH[a["type"]], a["count"]
        if "bufferView" in a:
            values = self._view_items(a["bufferView"], a.get("byteOffset", 0), count, dtype, width).copy()
        else:
            values = np.zeros((count, width), dtype=dtype)
        sparse = a.get("sparse")
        if sparse:
            idx = sparse["indices"]
            rows = self._view_items(idx["bufferView"], idx.get("byteOffset", 0), sparse["count"],
                                    DTYPES[idx["componentType"]], 1)[:, 0].astype(np.int64)
            assert np.all(np.diff(rows) > 0), "sparse indices must increase strictly"
            val = sparse["values"]
            values[rows] = self._view_items(val["bufferView"], val.get("byteOffset", 0), sparse["count"], dtype, width)
        if "min" in a:  # the stored bounds must be the values' bounds (before normalization)
            assert np.allclose(values.min(axis=0), a["min"]) and np.allclose(values.max(axis=0), a["max"]), index
        out = values.astype(np.float64)
        if a.get("normalized"):
            info = np.iinfo(dtype)
            out = np.maximum(out / info.max, -1.0) if info.min < 0 else out / info.max
        return out


def node_matrix(node):
    """4x4 local transform of a node from its TRS (or matrix)."""
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    M = np.eye(4)
    M[:3, :3] = R * np.asarray(node.get("scale", [1, 1, 1]))
    M[:3, 3] = node.get("translation", [0, 0, 0])
    return M


def animated_frames(data):
    """Every key of the file's first animation: (times (f,), world vertices (f, n, 3) float64,
    faces (m, 3), shown target per key (f,)). Checks that each key shows exactly one target."""
    glb = Glb(data)
    doc = glb.json
    (animation,) = doc["animations"]
    samplers = animation["samplers"]
    times = None
    channels = {}
    for channel in animation["channels"]:
        sampler = samplers[channel["sampler"]]
        t = glb.accessor(sampler["input"])[:, 0]
        times = t if times is None else times
        assert np.array_equal(t, times), "all channels share the frame times"
        channels[(channel["target"]["node"], channel["target"]["path"])] = glb.accessor(sampler["output"])
    mesh_node = next(i for i, node in enumerate(doc["nodes"]) if "mesh" in node)
    parent = next(i for i, node in enumerate(doc["nodes"]) if mesh_node in node.get("children", []))
    primitive = doc["meshes"][doc["nodes"][mesh_node]["mesh"]]["primitives"][0]
    base = glb.accessor(primitive["attributes"]["POSITION"])
    targets = [glb.accessor(t["POSITION"]) for t in primitive["targets"]]
    faces = glb.accessor(primitive["indices"]).astype(np.int64).reshape(-1, 3)
    weights = channels[(mesh_node, "weights")].reshape(len(times), len(targets))
    shown = weights.argmax(axis=1)
    assert np.all(np.sort(weights, axis=1)[:, -1] == 1.0) and np.all(weights.sum(axis=1) == 1.0), \
        "each key shows exactly one target"
    mesh_matrix = node_matrix(doc["nodes"][mesh_node])
    out = np.empty((len(times), len(base), 3))
    for k in range(len(times)):
        root = dict(doc["nodes"][parent])
        root["translation"] = channels[(parent, "translation")][k].tolist()
        root["rotation"] = channels[(parent, "rotation")][k].tolist()
        M = node_matrix(root) @ mesh_matrix
        local = base + targets[shown[k]]
        out[k] = local @ M[:3, :3].T + M[:3, 3]
    return times, out, faces, shown

"""A binary glTF 2.0 container: one buffer of aligned buffer views, accessors, and the GLB framing.

``glb = GlbBuffer()``; ``view = glb.view(data, target=ARRAY_BUFFER, stride=8)``;
``glb.accessor(view, SHORT, count, "VEC3", ...)`` returns accessor indices to put in the
glTF JSON; ``glb.to_bytes(document)`` adds ``buffers``, ``bufferViews`` and ``accessors`` to the
document and frames it as a .glb (glTF 2.0 specification, section 4.4: a 12-byte header, a JSON
chunk padded with spaces, a BIN chunk padded with zeros, every chunk 4-byte aligned).
"""

from __future__ import annotations

import json
import struct

import numpy as np

BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT, UNSIGNED_INT, FLOAT = 5120, 5121, 5122, 5123, 5125, 5126
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
COMPONENT_DTYPE = {BYTE: "<i1", UNSIGNED_BYTE: "<u1", SHORT: "<i2", UNSIGNED_SHORT: "<u2", UNSIGNED_INT: "<u4",
                   FLOAT: "<f4"}
COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
MAGIC, JSON_CHUNK, BIN_CHUNK = 0x46546C67, 0x4E4F534A, 0x004E4942


def index_component(n):
    """The smallest unsigned component type that can index ``n`` items (UNSIGNED_BYTE/SHORT/INT)."""
    if n <= 0xFF:
        return UNSIGNED_BYTE
    if n <= 0xFFFF:
        return UNSIGNED_SHORT
    return UNSIGNED_INT


class GlbBuffer:
    """The binary chunk of a GLB being assembled, with its buffer views and accessors."""

    def __init__(self):
        self.parts = []
        self.length = 0
        self.views = []
        self.accessors = []

    def view(self, data, target=None, stride=None):
        """Append ``data`` (bytes or an array, written little-endian as it is) as a buffer view,
        starting at a 4-byte boundary; returns its index."""
        data = data.tobytes() if isinstance(data, np.ndarray) else bytes(data)
        pad = -self.length % 4
        if pad:
            self.parts.append(b"\0" * pad)
            self.length += pad
        entry = {"buffer": 0, "byteOffset": self.length, "byteLength": len(data)}
        if stride is not None:
            entry["byteStride"] = int(stride)
        if target is not None:
            entry["target"] = int(target)
        self.parts.append(data)
        self.length += len(data)
        self.views.append(entry)
        return len(self.views) - 1

    def accessor(self, view, component, count, kind, *, offset=0, normalized=False, minimum=None, maximum=None,
                 sparse=None):
        """Add an accessor; ``view`` None with no ``sparse`` reads as zeros. Returns its index."""
        entry = {"componentType": int(component), "count": int(count), "type": kind}
        if view is not None:
            entry["bufferView"] = int(view)
            if offset:
                entry["byteOffset"] = int(offset)
        if normalized:
            entry["normalized"] = True
        if minimum is not None:
            entry["min"] = _numbers(minimum, component)
            entry["max"] = _numbers(maximum, component)
        if sparse is not None:
            entry["sparse"] = sparse
        self.accessors.append(entry)
        return len(self.accessors) - 1

    def array_accessor(self, array, component, kind, *, target=None, bounds=False):
        """A tightly packed accessor holding ``array`` (rows are elements); returns its index."""
        array = np.ascontiguousarray(array, dtype=COMPONENT_DTYPE[component])
        rows = array.reshape(len(array), -1)
        view = self.view(array, target=target)
        minimum = rows.min(axis=0) if bounds else None
        maximum = rows.max(axis=0) if bounds else None
        return self.accessor(view, component, len(array), kind, minimum=minimum, maximum=maximum)

    def to_bytes(self, document):
        """The GLB file: ``document`` (a glTF JSON dict) completed with the buffer, views, accessors."""
        binary = b"".join(self.parts)
        binary += b"\0" * (-len(binary) % 4)
        document = dict(document, buffers=[{"byteLength": len(binary)}], bufferViews=self.views,
                        accessors=self.accessors)
        text = json.dumps(document, separators=(",", ":"), allow_nan=False).encode("utf-8")
        text += b" " * (-len(text) % 4)
        total = 12 + 8 + len(text) + 8 + len(binary)
        return b"".join([struct.pack("<III", MAGIC, 2, total), struct.pack("<II", len(text), JSON_CHUNK), text,
                         struct.pack("<II", len(binary), BIN_CHUNK), binary])


def _numbers(values, component):
    """JSON numbers for accessor bounds: integers for integer components, floats as stored (float32)."""
    values = np.asarray(values).ravel()
    if component == FLOAT:
        return [float(np.float32(v)) for v in values.tolist()]
    return [int(v) for v in values.tolist()]

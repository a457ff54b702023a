"""``python -m server.heatmap.worker``: the heatmap helper process (see server/heatmap/__init__.py).

Reads jobs from stdin, each a framed msgpack map (server/heatmap/codec.py) ``{"id", "space"
(path), "checksum", "derived" (directory or nil), "weights" (float64 bytes), "phase", "vertices"
(float32 bytes, the frame's vertices in metres), "seq"}``, and answers each on stdout with
``{"id", "seq", "error_um", "error_max"}`` or ``{"id", "error"}``. Exits when stdin closes.
"""

from __future__ import annotations

import sys
import time

import msgpack
import numpy as np

from server.heatmap.codec import DUTY, encode_distances, framed


class Blenders:
    """The non-linear blender of each space asked for, opened once (memory-mapped)."""

    def __init__(self):
        self._open = {}   # (path, checksum) -> (space, blender)

    def get(self, path, checksum, derived):
        key = (path, checksum)
        entry = self._open.get(key)
        if entry is None:
            from engine.motion_space import MotionSpace
            from engine.motion_space.derived import DerivedStore

            space = MotionSpace.open(path, verify=False, derived=DerivedStore(derived) if derived else None)
            if space.container.checksum != checksum:
                space.close()
                raise ValueError(f"{path} has changed since the server opened it")
            entry = self._open[key] = (space, space.new_blender("nonlinear"))
        return entry[1]


def answer(blenders, job):
    """The reply to one job."""
    try:
        blender = blenders.get(job["space"], job["checksum"], job["derived"])
        weights = np.frombuffer(job["weights"], dtype="<f8")
        vertices = np.frombuffer(job["vertices"], dtype="<f4").reshape(-1, 3)
        reference = blender.blend(weights, float(job["phase"]))
        error_um, error_max = encode_distances(np.linalg.norm(vertices - reference, axis=1))
        return {"id": job["id"], "seq": job["seq"], "error_um": error_um, "error_max": error_max}
    except Exception as exc:  # noqa: BLE001 - reported to the server, which logs it; the helper goes on
        return {"id": job.get("id"), "error": f"{type(exc).__name__}: {exc}"}


def read_exactly(stream, n):
    data = stream.read(n)
    return data if data is not None and len(data) == n else None


def main():
    source, sink = sys.stdin.buffer, sys.stdout.buffer
    blenders = Blenders()
    while True:
        head = read_exactly(source, 4)
        body = read_exactly(source, int.from_bytes(head, "little")) if head is not None else None
        if body is None:
            return 0  # the server closed the pipe: it has stopped
        started = time.perf_counter()
        sink.write(framed(answer(blenders, msgpack.unpackb(body, raw=False))))
        sink.flush()
        busy = time.perf_counter() - started
        time.sleep(min(busy * (1 - DUTY) / DUTY, 0.2))  # a quarter of the time at most


if __name__ == "__main__":
    sys.exit(main())

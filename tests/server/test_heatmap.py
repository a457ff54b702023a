"""server/heatmap/: the helper process answers heatmap jobs with the distances from the
non-linear blend, reports bad jobs without dying, and ends when its input closes."""

from __future__ import annotations

import subprocess
import sys

import msgpack
import numpy as np
import pytest

from engine.motion_space import MotionSpace
from server.heatmap.codec import encode_distances, framed


@pytest.fixture(scope="module")
def speed_path(built_spaces):
    return built_spaces / "speed.mspace"


def job(space, vertices, weights, phase, job_id, seq):
    return {"id": job_id, "space": str(space.container.path), "checksum": space.container.checksum, "derived": None,
            "weights": np.asarray(weights, dtype="<f8").tobytes(), "phase": phase,
            "vertices": np.asarray(vertices, dtype="<f4").tobytes(), "seq": seq}


def read_reply(stream):
    head = stream.read(4)
    return msgpack.unpackb(stream.read(int.from_bytes(head, "little")), raw=False)


def test_the_helper_answers_with_the_distances_from_the_nonlinear_blend(speed_path):
    with MotionSpace.open(speed_path) as space:
        weights, phase = np.array([0.3, 0.7]), 0.4
        linear = np.asarray(space.blend(weights, phase, "linear"), dtype=np.float32)
        expected = encode_distances(np.linalg.norm(linear - space.blend(weights, phase, "nonlinear"), axis=1))
        helper = subprocess.Popen([sys.executable, "-m", "server.heatmap.worker"], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE)
        try:
            helper.stdin.write(framed(job(space, linear, weights, phase, 7, 12)))
            helper.stdin.write(framed({**job(space, linear, weights, phase, 8, 13), "checksum": "not it"}))
            helper.stdin.flush()
            first, second = read_reply(helper.stdout), read_reply(helper.stdout)
            helper.stdin.write(framed(job(space, linear, weights, phase, 9, 14)))  # it goes on after a failure
            helper.stdin.flush()
            third = read_reply(helper.stdout)
        finally:
            helper.stdin.close()
            code = helper.wait(30)
    assert (first["id"], first["seq"]) == (7, 12)
    assert first["error_um"] == expected[0] and first["error_max"] == pytest.approx(expected[1], abs=1e-9)
    assert first["error_max"] > 0  # linear is not the non-linear blend
    assert second["id"] == 8 and "has changed since the server opened it" in second["error"]
    assert (third["id"], third["error_um"]) == (9, expected[0])
    assert code == 0  # its input closed: it ended by itself

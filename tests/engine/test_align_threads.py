"""The same alignment whatever the BLAS thread count: a machine with more cores gets the same bytes.

OpenBLAS splits a long dot product over its threads, and the partial sums follow their number: the
volume-weighted distortion of a studio-tiny frame (over 10,000 tets) came out one unit in the last
place apart between one thread and eight, and the distortion feeds the confidence, the repair and
the root race.
"""

import contextlib
import io

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from engine.align import align_captures
from engine.mesh_io import read_frames
from server.cli import main


@pytest.fixture(scope="module")
def walk_frames(tmp_path_factory):
    data = tmp_path_factory.mktemp("captures") / "studio-tiny"
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        assert main(["synth", "--preset", "studio-tiny", "--only", "walk", "--no-previews", "--out", str(data)]) == 0
    return read_frames(data / "sequences" / "walk" / "unstructured")[:6]


def test_an_alignment_is_the_same_on_one_blas_thread_and_on_eight(walk_frames):
    aligned = {}
    for threads in (1, 8):
        with threadpool_limits(threads, user_api="blas"):
            aligned[threads] = align_captures(walk_frames, np.array([len(walk_frames)]), workers=1,
                                              repair_budget=0).aligned
    one, eight = aligned[1], aligned[8]
    for field in ("vertices", "residual", "residual_max", "distortion", "distortion_tail", "confidence", "parent"):
        assert getattr(one, field).tobytes() == getattr(eight, field).tobytes(), field

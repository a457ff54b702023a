"""The studio's packaged data: the MakeHuman body and the CMU takes (see data/CREDITS.md).

The only place in the studio generator that reads files: package data under
``engine/synthetic/data/``, committed to the repository, never downloaded at run time.
"""

from __future__ import annotations

import gzip
from functools import lru_cache
from importlib import resources

import numpy as np

from engine.synthetic.studio.bvh import parse_bvh

TAKES = ("002_01", "002_03", "002_04", "002_05", "005_02", "005_06", "005_17", "007_01", "007_04", "007_12")
BVH_UNITS = 0.01  # the takes are in centimetres


def _data():
    return resources.files("engine.synthetic").joinpath("data")


@lru_cache(maxsize=1)
def makehuman_body():
    """The body arrays of ``makehuman_body.npz`` as a dict (read-only arrays)."""
    with resources.as_file(_data().joinpath("makehuman_body.npz")) as path:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    for array in arrays.values():
        array.setflags(write=False)
    return arrays


@lru_cache(maxsize=len(TAKES))
def mocap_take(name):
    """A CMU take as a parsed ``Bvh`` (centimetres, Y up, 60 fps)."""
    if name not in TAKES:
        raise ValueError(f"unknown take {name!r}; the studio has {', '.join(TAKES)}")
    text = gzip.decompress(_data().joinpath("mocap", f"{name}.bvh.gz").read_bytes()).decode()
    return parse_bvh(text, source=f"{name}.bvh.gz")

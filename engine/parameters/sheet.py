"""Where a parameter layout lets a player go, as blend weights: the sheet the hybrid is bounded on."""

from __future__ import annotations

import numpy as np


def sheet_resolution(layout):
    """Test points per axis of a layout's sheet: 33 along a chain, 17 x 17 on a two-dimensional sheet."""
    return 33 if layout.dims == 1 else 17


def sheet_coordinates(layout, resolution=None):
    """(M, dims) layout coordinates u of ``sheet_weights``' rows: ``resolution`` per axis in [0, 1],
    the last axis fastest."""
    axis = np.linspace(0.0, 1.0, resolution or sheet_resolution(layout))
    if layout.dims == 1:
        return axis[:, None]
    return np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)


def sheet_weights(layout, resolution=None):
    """(M, N) blend weights covering a parameter layout's sheet: where the player can go."""
    return np.array([layout.weights(list(u)) for u in sheet_coordinates(layout, resolution)])


def between_weights(layout, resolution=None):
    """(K, N) blend weights halfway between ``sheet_weights(layout, resolution)``'s: the sheet at
    twice the density without the test points themselves (32 along a chain, 800 on a 17 x 17 sheet)."""
    resolution = resolution or sheet_resolution(layout)
    dense = sheet_weights(layout, 2 * resolution - 1)
    if layout.dims == 1:
        return dense[1::2]
    odd = np.arange(2 * resolution - 1) % 2 == 1
    between = odd[:, None] | odd[None, :]
    return dense[between.ravel()]

"""What the heatmap helper and the service share: the distances' encoding, the duty cycle and
the framing of their messages on the helper's pipes (a 4-byte little-endian length, then a
msgpack map)."""

from __future__ import annotations

import msgpack
import numpy as np

DUTY = 0.25   # the share of the time the helper process may work


def encode_distances(distance):
    """(error_um bytes: uint16 micrometres, saturating; error_max in metres) of (n,) distances."""
    return np.minimum(np.rint(distance * 1e6), 65535).astype("<u2").tobytes(), float(distance.max())


def framed(message):
    """A message (a dict of msgpack types) as the bytes written on a pipe."""
    body = msgpack.packb(message, use_bin_type=True)
    return len(body).to_bytes(4, "little") + body

"""Natural ("human") ordering of frame file names: frame_2 before frame_10."""

from __future__ import annotations

import re

_DIGITS = re.compile(r"(\d+)")


def natural_key(name):
    """Sort key that compares runs of digits as numbers and the rest case-insensitively.

    Parameters
    ----------
    name : str   a file name or zip member path

    Returns
    -------
    key : tuple   ``sorted(names, key=natural_key)`` puts frame_9.obj before frame_10.obj

    Notes
    -----
    The name is split into alternating text and digit runs; text compares case-folded, digit
    runs by value, and a number sorts before a text run at the same position
    (``2.obj`` < ``10.obj`` < ``a.obj``), so names with different prefixes never compare a
    string with an int. Names that tie (``frame_01`` and ``frame_1``, or names differing only
    in case) are ordered by the plain string, so the order is total and reproducible.
    """
    parts = _DIGITS.split(str(name))
    key = []
    for i, part in enumerate(parts):
        if i % 2:
            key.append((0, int(part), ""))
        elif part:
            key.append((1, 0, part.casefold()))
    return (tuple(key), str(name))

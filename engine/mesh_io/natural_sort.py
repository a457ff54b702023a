"""Natural ("human") ordering of frame file names: frame_2 before frame_10."""

from __future__ import annotations

import re
from pathlib import PurePosixPath

_DIGITS = re.compile(r"(\d+)")
_TRAILING_DIGITS = re.compile(r"\d+$")


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


def name_stem(name):
    """The part of a frame's file name that is not its frame number.

    Parameters
    ----------
    name : str   a file name or zip member path

    Returns
    -------
    stem : str   the file name without its folder, extension and trailing digits:
                 ``take1/frame_0012.obj`` -> ``frame_``, ``0012.ply`` -> ``""``
    """
    return _TRAILING_DIGITS.sub("", PurePosixPath(str(name)).stem)


def stem_runs(names):
    """Runs of consecutive names with the same `name_stem` (compared case-insensitively).

    Parameters
    ----------
    names : list of str   frame names, e.g. in natural order

    Returns
    -------
    runs : list of (str, int, int)
        (stem as the run's first name spells it, index of its first name, index of its last);
        one run when every name has the same stem, ``[]`` for no names
    """
    runs = []
    for i, name in enumerate(names):
        stem = name_stem(name)
        if runs and runs[-1][0].casefold() == stem.casefold():
            runs[-1] = (runs[-1][0], runs[-1][1], i)
        else:
            runs.append((stem, i, i))
    return runs

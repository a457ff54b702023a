"""Vectorised tokenising of whitespace-separated text, shared by the OBJ, OFF and PLY parsers.

Splitting a 100k-line file with a Python loop per token is slow; these helpers work on the raw
bytes with NumPy and leave Python loops to the error path.
"""

from __future__ import annotations

import numpy as np

_WHITESPACE = np.zeros(256, dtype=bool)
_WHITESPACE[[ord(c) for c in " \t\n\r\v\f"]] = True


def tokens_per_line(text, n_lines):
    """Count whitespace-separated tokens on each line.

    Parameters
    ----------
    text : bytes     lines joined by b"\\n" (no trailing newline needed)
    n_lines : int    number of lines in `text`

    Returns
    -------
    counts : (n_lines,) int64 array
    """
    codes = np.frombuffer(text, dtype=np.uint8)
    space = _WHITESPACE[codes]
    starts = ~space
    starts[1:] &= space[:-1]
    line = np.cumsum(codes == ord("\n"))
    return np.bincount(line[starts], minlength=n_lines).astype(np.int64)


def first_field_of_tokens(text, separator=b"/"):
    """Blank out everything from the first `separator` to the end of each token.

    ``b"1/4/7 2//8 3"`` becomes ``b"1     2    3"``: OBJ face corners keep only the vertex
    index while the text keeps its length and line structure.

    Parameters
    ----------
    text : bytes

    Returns
    -------
    text : bytes   same length
    """
    codes = np.frombuffer(text, dtype=np.uint8)
    is_separator = codes == separator[0]
    if not is_separator.any():
        return text
    space = _WHITESPACE[codes]
    starts = ~space
    starts[1:] &= space[:-1]
    token = np.cumsum(starts) - 1  # token number of every byte (whitespace: the one before)
    seen = np.cumsum(is_separator)
    seen_before_token = (seen - is_separator)[starts]
    after = ~space & (token >= 0)
    after[after] = seen[after] > seen_before_token[token[after]]
    blanked = codes.copy()
    blanked[after] = ord(" ")
    return blanked.tobytes()

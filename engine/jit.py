"""Compiling the engine's inner loops with numba: :func:`compiled`.

The alignment's correspondence searches (engine/align/compiled.py) and the stream's per-frame
blends and casts (engine/blend/compiled.py) are loops over points or rows whose numpy
formulations pay a pass over memory, and a temporary, per operation; compiled, each is one pass.
"""

from __future__ import annotations

from numba import njit


def compiled(function):
    """``function`` compiled with numba (no fast-math: the same IEEE operations, in the order
    written), its machine code cached on disk where numba can write: beside the defining file,
    else numba's per-user cache (or ``NUMBA_CACHE_DIR``). Where neither is writable (a read-only
    install run by a user without a writable home: numba refuses to cache there with a
    RuntimeError at import), it is compiled in every process instead (a few seconds the first
    time it is called)."""
    try:
        return njit(cache=True, nogil=True)(function)
    except RuntimeError:
        return njit(nogil=True)(function)

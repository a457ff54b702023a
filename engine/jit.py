"""Compiling the engine's inner loops with numba: :func:`compiled`.

The alignment's correspondence searches (engine/align/compiled.py) and the stream's per-frame
blends and casts (engine/blend/compiled.py) are loops over points or rows whose numpy
formulations pay a pass over memory, and a temporary, per operation; compiled, each is one pass.
"""

from __future__ import annotations

from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic


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


@intrinsic
def float64_pointer(typingctx, address):  # pragma: no cover (compiled code only)
    """In compiled code, an int64 ``address`` (an array's ``ctypes.data``) as a float64 pointer,
    for ``numba.carray(float64_pointer(address), shape)``: many small arrays reached from one
    array of their addresses (a tick's players' clocks: engine/player_steps.py), where passing
    them as a list would cost a conversion each. The caller keeps the arrays alive."""
    signature = types.CPointer(types.float64)(types.int64)

    def codegen(context, builder, sig, args):
        return builder.inttoptr(args[0], context.get_value_type(sig.return_type))
    return signature, codegen


@intrinsic
def copy_bytes(typingctx, out, at, source, start, n):  # pragma: no cover (compiled code only)
    """In compiled code, ``out[at:at + n] = source[start:start + n]`` for contiguous uint8 arrays
    as one ``memcpy`` (a slice assignment there is a loop of one byte a step). No bounds checks:
    the caller's."""
    signature = types.none(out, at, source, start, n)

    def codegen(context, builder, sig, args):
        destination = context.make_array(sig.args[0])(context, builder, args[0])
        origin = context.make_array(sig.args[2])(context, builder, args[2])
        cgutils.memcpy(builder, builder.gep(destination.data, [args[1]]), builder.gep(origin.data, [args[3]]), args[4])
        return context.get_dummy_value()
    return signature, codegen

"""Exact non-linear (volumetric, rotation-aware) mesh blending (Casas et al. 2012, section 4.1).

Source frames are decomposed once (``engine.blend.decompose``) into per-tet rotations
(quaternions), symmetric stretches and surface detail in the local frame of its tet's rotation.
A blend averages the rotations (sign-aligned quaternions, normalised), blends the stretches
linearly, solves one prefactored least-squares system for the tet vertices (eq. 2 in gradient
form), reads the surface off the embedding and adds the blended detail rotated by the blended
rotations. Weights e_i give back source i exactly.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from engine.blend.decompose import (
    SYMMETRIC,
    FrameDecomposer,
    FrameDecomposition,
    VolumetricEmbedding,
    decompose_frames,
)
from engine.blend.phase import phase_of_sample, phase_samples
from engine.deform import DeformationSolver

# The 3 x 3 symmetric stretch from its 6 stored components, row-major.
_STRETCH_ENTRIES = np.array([[SYMMETRIC.index((min(i, j), max(i, j))) for j in range(3)] for i in range(3)]).ravel()


def component_major_layout(quaternions, stretch, detail):
    """The arrays NonlinearBlender blends from, in the order its hot path reads them.

    quaternions : (m, t, 4), stretch : (m, t, 6), detail : (m, n, 3) float arrays
    Returns
    layout : dict   ``quaternions`` (m, 4, t), ``stretch`` (m, 6, t), ``detail`` (m, 3, n)
                    C-contiguous float32 arrays
    """
    return {"quaternions": _component_major(quaternions), "stretch": _component_major(stretch),
            "detail": _component_major(detail)}


def _component_major(A):
    """(m, k, c) float32 copy of an (m, c, k) array: components as contiguous rows."""
    return np.ascontiguousarray(np.swapaxes(np.asarray(A, dtype=np.float32), 1, 2))


def anchored_offset(delta, dispersion, floor=1e-3, share=None):
    """Translation placing a non-linear blend relative to the linear blend of the same frames.

    Parameters
    ----------
    delta : (n, 3) float array       per-vertex offsets, non-linear minus linear
    dispersion : (n,) float array    how much the sources disagree on the rotation at each vertex
                                     (weighted quaternion variance, 0 = all rotate alike)
    floor : float                    dispersion below which vertices count as fully rigid
    share : (n,) float array or None each vertex's share of its place
                                     (``VolumetricEmbedding.surface_share``; None: 1 each)

    Returns
    -------
    t : (3,) float array   weighted mean of ``delta``, weights share / (floor + dispersion)

    Notes
    -----
    The solve fixes the blend's shape up to a translation. Anchoring it where the sources agree
    on the rotation (the torso of a walk and a jog) makes non-linear and linear blends coincide
    there and leaves the difference in the parts that rotate (the limbs), so hybrid corrections
    stay sparse. When every part rotates alike (a rigid rotation), the weights are uniform and
    the centroids coincide, which places a rotation-interpolated rigid body exactly.
    ``NonlinearBlender`` computes the same weighted mean without forming ``delta``.
    """
    weight = 1.0 / (floor + dispersion)
    if share is not None:
        weight = weight * share
    return (weight @ delta) / weight.sum()


class _Part:
    """One blend of decomposed frames up to the solve (float32, component-major).

    F : (3, 3, t)    blended R S per tet, F[i, j] = entry (i, j)
    detail : (3, n)  blended surface detail rotated by the blended rotations
    linear : (n, 3)  linear blend of the frames' surfaces (where the placement anchors)
    dispersion : (n,) rotation dispersion at each surface vertex's tet
    """

    __slots__ = ("F", "detail", "linear", "dispersion")

    def __init__(self, t, n):
        self.F = np.empty((3, 3, t), dtype=np.float32)
        self.detail = np.empty((3, n), dtype=np.float32)
        self.linear = np.empty((n, 3), dtype=np.float32)
        self.dispersion = np.empty(n, dtype=np.float32)


class NonlinearBlender:
    """Exact non-linear blends of decomposed source frames.

    ``blender = NonlinearBlender(embedding, quaternions, stretch, detail, surfaces)`` prefactors
    the solve; ``blender.blend_frames(coefficients, frames)`` is the hot path.

    Parameters
    ----------
    embedding : VolumetricEmbedding
    quaternions : (m, t, 4) float array   per decomposed frame (any layout flattened to m)
    stretch : (m, t, 6) float array
    detail : (m, n, 3) float array
    surfaces : (m, n, 3) float array      the source frames themselves (for the placement)

    Notes
    -----
    Rotations are averaged as sign-aligned, weighted quaternion sums normalised per tet (the
    hemisphere of the heaviest contributor); stretches and detail blend linearly; one
    prefactored solve gives the tet vertices. The solve fixes the shape up to a translation,
    chosen by ``anchored_offset``: the blend coincides with the linear blend where the sources
    agree on the rotation, so the non-linear difference stays in the parts that rotate (the
    limbs). With weights e_i every choice gives back source i exactly.

    Cost: the per-tet work runs in float32 on component-major rows (one contiguous length-t
    row per quaternion, stretch or gradient entry) into preallocated buffers; the solve and
    the surface are float64. At 10,000 surface vertices and 14,700 tets a blend between two
    phase samples takes about 1.2 ms on one core: two rotation blends of 0.3 ms, one solve of
    0.3 ms (half of it the sparse product for the right-hand side), the surface and placement.
    """

    RECENT = 4  # blends before the solve kept (a player at fixed weights reuses its two samples)

    def __init__(self, embedding, quaternions, stretch, detail, surfaces, layout=None):
        self.embedding = embedding
        self.quaternions, self.stretch, self.detail = quaternions, stretch, detail  # as given
        # Component-major copies, (m, 4, t), (m, 6, t), (m, 3, n). ``layout``: those arrays made
        # beforehand (component_major_layout), e.g. mapped from a file several processes share
        # (engine/motion_space/derived.py); only read.
        layout = layout if layout is not None else component_major_layout(quaternions, stretch, detail)
        self._q, self._s, self._d = layout["quaternions"], layout["stretch"], layout["detail"]
        self.surfaces = surfaces
        self._surfaces = np.asarray(surfaces, dtype=np.float32).reshape(len(surfaces), -1)
        self.solver = DeformationSolver(embedding.V_tet, embedding.T)
        self.B = embedding.B.tocsr()
        self.surface_tet = np.asarray(embedding.surface_tet, dtype=np.intp)
        t, n = len(embedding.T), len(self.surface_tet)
        # a solid in several parts (a floating piece of surface filled on its own): each part
        # is placed by its own anchored offset (None: one part, one offset)
        self._surface_part = None
        if self.solver.n_parts > 1:
            self._surface_part = self.solver.part[np.asarray(embedding.T)[self.surface_tet, 0]]
        self.n_tets, self.n_vertices = t, n
        # copies of one point (a triangle soup) share their weight in the placement
        share = embedding.surface_share
        self._share = None if share is None else share.astype(np.float32)
        f32 = np.float32
        # scratch of the per-tet work
        self._qb = np.empty((4, t), dtype=f32)
        self._q4 = np.empty((4, t), dtype=f32)
        self._dot = np.empty(t, dtype=f32)
        self._signed = np.empty(t, dtype=f32)
        self._agreement = np.empty(t, dtype=f32)
        self._pairs = np.empty((9, t), dtype=f32)
        self._R = np.empty((3, 3, t), dtype=f32)
        self._S = np.empty((3, 3, t), dtype=f32)
        self._RS = np.empty((3, 3, t), dtype=f32)
        self._s6 = np.empty(6 * t, dtype=f32)
        self._d3 = np.empty(3 * n, dtype=f32)
        self._qs = np.empty((4, n), dtype=f32)
        self._uv = np.empty((3, n), dtype=f32)
        self._uuv = np.empty((3, n), dtype=f32)
        self._detail = np.empty((3, n), dtype=f32)
        # scratch of the solve and the surface
        self._F = np.empty((3, 3, t))
        self._F32 = np.empty((3, 3, t), dtype=f32)
        self._X = np.empty((len(embedding.V_tet), 3))
        self._weight = np.empty(n, dtype=f32)
        self._recent = OrderedDict()
        self._spare = []  # _Part buffers evicted from _recent, reused

    def _parts(self, coefficients, frames):
        """The blend of decomposed frames ``frames`` up to the solve (a ``_Part``).

        The last few are kept: a player at fixed weights asks for the same phase sample on
        consecutive frames (as one end of the interval, then the other)."""
        coefficients = np.asarray(coefficients, dtype=np.float64)
        frames = np.asarray(frames, dtype=np.int64)
        key = (coefficients.tobytes(), frames.tobytes())
        part = self._recent.get(key)
        if part is None:
            while len(self._recent) >= self.RECENT:
                self._spare.append(self._recent.popitem(last=False)[1])
            part = self._spare.pop() if self._spare else _Part(self.n_tets, self.n_vertices)
            self._compute_parts(coefficients, frames, part)
            self._recent[key] = part
        return part

    def _rows(self, array, frames, coefficients):
        """sum_c coefficients[c] * array[frames[c]] as one flat float32 row (a BLAS gemv)."""
        first = int(frames[0])
        if np.array_equal(frames, np.arange(first, first + len(frames))):
            stacked = array[first:first + len(frames)].reshape(len(frames), -1)  # a view
        else:
            stacked = array[frames].reshape(len(frames), -1)
        return stacked, coefficients.astype(np.float32)

    def _compute_parts(self, coefficients, frames, part):
        keep = coefficients != 0
        coefficients, frames = coefficients[keep], frames[keep]
        if len(frames) == 0:
            raise ValueError("blend weights are all zero")
        f32 = np.float32
        # Rotation average: quaternions sign-aligned with the heaviest contributor's, summed with
        # the coefficients and normalised per tet.
        top = int(np.argmax(coefficients))
        q_top = self._q[frames[top]]
        qb, q4, dot, signed = self._qb, self._q4, self._dot, self._signed
        np.multiply(q_top, f32(coefficients[top]), out=qb)
        for c, frame in enumerate(frames):
            if c == top:
                continue
            q = self._q[frame]
            np.einsum("kt,kt->t", q, q_top, out=dot)
            np.copyto(signed, f32(coefficients[c]))
            np.negative(signed, out=signed, where=dot < 0)
            np.multiply(q, signed, out=q4)
            qb += q4
        np.einsum("kt,kt->t", qb, qb, out=dot)
        np.sqrt(dot, out=dot)
        qb /= dot
        # Dispersion: 1 - sum_c coefficient_c cos^2(half the angle from source c to the blend).
        agreement = self._agreement
        agreement[...] = 1.0
        for c, frame in enumerate(frames):
            np.einsum("kt,kt->t", self._q[frame], qb, out=dot)
            dot *= dot
            dot *= f32(coefficients[c])
            agreement -= dot
        np.take(agreement, self.surface_tet, out=part.dispersion)
        R = _rotations(qb, self._pairs, self._R)
        # Stretch: blended linearly, expanded to 3 x 3 rows.
        stacked, c32 = self._rows(self._s, frames, coefficients)
        np.dot(c32, stacked, out=self._s6)
        np.take(self._s6.reshape(6, -1), _STRETCH_ENTRIES, axis=0, out=self._S.reshape(9, -1))
        # F = R S, entry by entry over contiguous rows
        F, S, RS = part.F, self._S, self._RS
        np.multiply(R[:, 0, None, :], S[None, 0], out=F)
        for k in (1, 2):
            np.multiply(R[:, k, None, :], S[None, k], out=RS)
            F += RS
        # Detail: blended in the local frames, rotated by each surface vertex's tet rotation.
        stacked, c32 = self._rows(self._d, frames, coefficients)
        np.dot(c32, stacked, out=self._d3)
        np.take(qb, self.surface_tet, axis=1, out=self._qs)
        _rotate(self._qs, self._d3.reshape(3, -1), part.detail, self._uv, self._uuv)
        stacked, c32 = self._rows(self._surfaces, frames, coefficients)
        np.dot(c32, stacked, out=part.linear.reshape(-1))

    def blend_frames(self, coefficients, frames, out=None, *, then=None, a=0.0):
        """Blend decomposed frames ``frames`` (indices) with ``coefficients`` (summing to 1).

        With ``then = (coefficients, frames)`` and ``a`` in (0, 1), the result is (1 - a) times
        the first blend plus ``a`` times the second, computed with one solve (the solve is
        linear in the gradients); the placement offset uses the interpolated dispersion.

        Returns
        -------
        V : (n, 3) float array   blended surface (float64, or ``out``'s dtype)
        """
        first = self._parts(coefficients, frames)
        F, weight, detail = self._F, self._weight, self._detail
        if then is not None and a != 0.0:
            second = self._parts(*then)
            a32, b32 = np.float32(a), np.float32(1.0 - a)
            np.multiply(first.F, b32, out=self._F32)
            np.multiply(second.F, a32, out=F)
            F += self._F32
            np.multiply(first.detail, b32, out=detail)
            detail += second.detail * a32
            np.multiply(first.dispersion, b32, out=weight)
            weight += second.dispersion * a32
            pieces = ((first, 1.0 - a), (second, a))
        else:
            np.copyto(F, first.F)
            np.copyto(detail, first.detail)
            np.copyto(weight, first.dispersion)
            pieces = ((first, 1.0),)
        X = self.solver.solve_components(F, out=self._X)
        surface = self.B @ X
        surface += detail.T
        # anchored_offset(surface - linear, dispersion, share=...) without forming the difference
        weight += np.float32(1e-3)
        np.reciprocal(weight, out=weight)
        if self._share is not None:
            weight *= self._share
        if self._surface_part is not None:
            return self._place_parts(surface, weight, pieces, out)
        offset = weight @ surface
        for part, share in pieces:
            offset -= share * (weight @ part.linear)
        surface -= offset / float(weight.sum(dtype=np.float64))
        if out is not None:
            out[...] = surface
            return out
        return surface

    def _place_parts(self, surface, weight, pieces, out):
        """:meth:`blend_frames`'s placement for a solid in several parts: each part's surface
        vertices moved by their own anchored offset (the weighted mean of their difference from
        the linear blend), so every part lands where its sources put it."""
        label = self._surface_part
        count = self.solver.n_parts
        delta = surface.copy()
        for part, share in pieces:
            delta -= share * part.linear
        w = weight.astype(np.float64)
        mass = np.bincount(label, weights=w, minlength=count)
        offset = np.stack([np.bincount(label, weights=w * delta[:, c], minlength=count) for c in range(3)], axis=1)
        offset /= np.where(mass > 0, mass, 1.0)[:, None]
        surface -= offset[label]
        if out is not None:
            out[...] = surface
            return out
        return surface


def _cross(u, v, out):
    """Row-wise cross products of (3, n) arrays u and v into ``out`` (not aliasing u or v)."""
    np.multiply(u[1], v[2], out=out[0])
    out[0] -= u[2] * v[1]
    np.multiply(u[2], v[0], out=out[1])
    out[1] -= u[0] * v[2]
    np.multiply(u[0], v[1], out=out[2])
    out[2] -= u[1] * v[0]
    return out


def _rotate(q, v, out, uv, uuv):
    """Vectors v (3, n) rotated by unit quaternions q (4, n) (w, x, y, z), into ``out``:
    v + 2 w (u x v) + 2 u x (u x v) with u = (x, y, z). ``uv``, ``uuv`` (3, n) are scratch."""
    u = q[1:]
    _cross(u, v, uv)
    _cross(u, uv, uuv)
    uv *= q[0]
    uv += uuv
    uv *= 2.0
    np.add(v, uv, out=out)
    return out


def _rotations(q, pairs, R):
    """Rotation matrices of unit quaternions q (4, t) (w, x, y, z), written into R (3, 3, t):
    R[i, j] is entry (i, j) of every tet's rotation. ``pairs`` (9, t) is scratch."""
    w, x, y, z = q
    xx, yy, zz, xy, xz, yz, wx, wy, wz = pairs
    np.multiply(x, x, out=xx)
    np.multiply(y, y, out=yy)
    np.multiply(z, z, out=zz)
    np.multiply(x, y, out=xy)
    np.multiply(x, z, out=xz)
    np.multiply(y, z, out=yz)
    np.multiply(w, x, out=wx)
    np.multiply(w, y, out=wy)
    np.multiply(w, z, out=wz)
    pairs *= 2.0
    np.add(yy, zz, out=R[0, 0])
    np.add(xx, zz, out=R[1, 1])
    np.add(xx, yy, out=R[2, 2])
    for i in range(3):
        np.subtract(1.0, R[i, i], out=R[i, i])
    np.subtract(xy, wz, out=R[0, 1])
    np.add(xz, wy, out=R[0, 2])
    np.add(xy, wz, out=R[1, 0])
    np.subtract(yz, wx, out=R[1, 2])
    np.subtract(xz, wy, out=R[2, 0])
    np.add(yz, wx, out=R[2, 1])
    return R


class PhasedNonlinearBlender:
    """Exact non-linear blends of N sources on a phase grid.

    At a phase sample the blend is the exact non-linear blend of the N sources' frames there.
    Between samples p0 and p1 it is (1 - a) times the blend at p0 plus a times the blend at p1
    (one solve: the gradients are interpolated), as linear and hybrid blending interpolate in
    phase. Rotations are not interpolated in time: fast limbs turn by large angles between
    samples (a take-off's arm swing), where interpolating rotations would swing them the short
    way round; the sources themselves are defined on the grid.

    Parameters
    ----------
    blender : NonlinearBlender   over the P * N frames in phase-major order (frame p * N + i)
    n_phases, n_sources : int
    cyclic : bool
    """

    def __init__(self, blender, n_phases, n_sources, cyclic):
        self.blender = blender
        self.n_phases, self.n_sources, self.cyclic = int(n_phases), int(n_sources), bool(cyclic)

    def blend(self, weights, phase, out=None):
        """Blended vertices (n, 3) float64 at ``weights`` (N,) and ``phase`` in [0, 1]."""
        w = np.asarray(weights, dtype=np.float64)
        c = w / w.sum()
        p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
        i = np.arange(self.n_sources)
        if a == 0.0:
            return self.blender.blend_frames(c, p0 * self.n_sources + i, out=out)
        return self.blender.blend_frames(c, p0 * self.n_sources + i, out=out,
                                         then=(c, p1 * self.n_sources + i), a=a)

    def blend_all_phases(self, weights):
        """(P, n, 3) exact non-linear blend at every phase sample."""
        return np.stack([self.blend(weights, phase_of_sample(p, self.n_phases, self.cyclic))
                         for p in range(self.n_phases)])


__all__ = ["VolumetricEmbedding", "FrameDecomposer", "FrameDecomposition", "NonlinearBlender",
           "PhasedNonlinearBlender", "decompose_frames", "anchored_offset"]

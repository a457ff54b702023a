"""Exact non-linear (volumetric, rotation-aware) mesh blending (Casas et al. 2012, section 4.1).

The rest surface is embedded in a tetrahedral mesh. Each source frame is decomposed once: the
tet vertices are fitted to the frame's surface, each tet's deformation gradient is split by
polar decomposition into a rotation (quaternion) and a symmetric stretch, and what the embedded
tet mesh does not reproduce of the surface (its fine detail) is stored per vertex in the local
frame of its tet's rotation. A blend averages the rotations (sign-aligned quaternions,
normalised), blends the stretches linearly, solves one prefactored least-squares system for the
tet vertices (eq. 2 in gradient form), reads the surface off the embedding and adds the blended
detail rotated by the blended rotations. Weights e_i give back source i exactly.
"""

from __future__ import annotations

from collections import OrderedDict

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from engine.blend.phase import phase_of_sample, phase_samples
from engine.deform import DeformationSolver
from engine.tetmesh import (
    deformation_gradients,
    polar_decomposition,
    rotations_to_quaternions,
    tet_barycentric,
    tet_laplacian,
    tetrahedralize,
)

SYMMETRIC = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # stretch storage order


@dataclass(frozen=True)
class VolumetricEmbedding:
    """A rest surface embedded in a tetrahedral mesh.

    Attributes
    ----------
    V_tet : (k, 3) float array       rest tet vertices
    T : (t, 4) int array             tetrahedra
    surface_tet : (n, ) int array    the tet each surface vertex is embedded in
    surface_bary : (n, 4) float      its barycentric coordinates there (may extrapolate slightly)
    """

    V_tet: np.ndarray
    T: np.ndarray
    surface_tet: np.ndarray
    surface_bary: np.ndarray

    @classmethod
    def from_surface(cls, V, F, **tetrahedralize_options):
        """Tetrahedralise a rest surface (holes are capped) and embed its vertices.

        ``tetrahedralize_options`` go to :func:`engine.tetmesh.tetrahedralize` (resolution,
        cell, min_inside). Deterministic: the same surface gives the same embedding.
        """
        V_tet, T = tetrahedralize(V, F, **tetrahedralize_options)
        tet, bary, _ = tet_barycentric(V, V_tet, T)
        return cls(V_tet=V_tet, T=T, surface_tet=np.asarray(tet, dtype=np.int64), surface_bary=bary)

    @property
    def B(self):
        """(n, k) csr_matrix: surface vertices as combinations of tet vertices."""
        n = len(self.surface_tet)
        rows = np.repeat(np.arange(n), 4)
        return sp.csr_matrix((self.surface_bary.ravel(), (rows, self.T[self.surface_tet].ravel())),
                             shape=(n, len(self.V_tet)))


def _stretch_to_vector(S):
    return np.stack([S[..., i, j] for i, j in SYMMETRIC], axis=-1)


@dataclass(frozen=True)
class FrameDecomposition:
    """One source frame in blendable form.

    Attributes
    ----------
    quaternions : (t, 4) float array   per-tet rotation (w, x, y, z)
    stretch : (t, 6) float array       per-tet symmetric stretch (xx, yy, zz, xy, xz, yz)
    detail : (n, 3) float array        surface residual in the local frame of its tet's rotation
    """

    quaternions: np.ndarray
    stretch: np.ndarray
    detail: np.ndarray


class FrameDecomposer:
    """Fits the tet mesh to surface frames and decomposes them (done once per source frame).

    ``decomposer = FrameDecomposer(embedding)`` factors the fitting system once;
    ``decomposer.decompose(S)`` handles one frame.

    Parameters
    ----------
    embedding : VolumetricEmbedding
    fit_weight : float      weight of the surface constraints relative to the Laplacian's scale
    iterations : int        as-rigid-as-possible refinements of the interior (rotation targets)

    Notes
    -----
    The fit minimises ||G X - G_target||_D^2 + w^2 ||B X - S||^2 (eq. 2), first with the
    frame's best-fitting global rotation as every tet's target (so a rigid motion is fitted
    exactly), then with the rotations of the previous fit (local/global ARAP steps), so
    interior tets follow the surface rigidly where they can.
    """

    def __init__(self, embedding, *, fit_weight=30.0, iterations=2):
        self.embedding = embedding
        self.B = embedding.B
        L = tet_laplacian(embedding.V_tet, embedding.T)
        self.weight = float(np.sqrt(fit_weight * L.diagonal().mean()))
        self.solver = DeformationSolver(embedding.V_tet, embedding.T, constraints=self.B,
                                        constraint_weight=self.weight)
        self.iterations = int(iterations)
        self.rest_surface = np.asarray(self.B @ embedding.V_tet)

    def fit(self, S):
        """Tet vertex positions (k, 3) fitted to surface frame S (n, 3)."""
        T, V_tet = self.embedding.T, self.embedding.V_tet
        X = self.solver.solve(_stacked(np.broadcast_to(_best_rotation(self.rest_surface, S), (len(T), 3, 3))), S)
        for _ in range(self.iterations):
            R, _ = polar_decomposition(deformation_gradients(V_tet, X, T))
            X = self.solver.solve(_stacked(R @ _rest_frames(len(T))), S)
        return X

    def decompose(self, S):
        """Fit the tet mesh to S and split it into rotations, stretches and local detail."""
        S = np.asarray(S, dtype=np.float64)
        emb = self.embedding
        X = self.fit(S)
        F = deformation_gradients(emb.V_tet, X, emb.T)
        R, Sy = polar_decomposition(F)
        q = rotations_to_quaternions(R)
        residual = S - self.B @ X
        R_surface = R[emb.surface_tet]
        detail = np.einsum("nba,nb->na", R_surface, residual)  # R^T r
        return FrameDecomposition(quaternions=q, stretch=_stretch_to_vector(Sy), detail=detail)


def _component_major(A):
    """(m, k, c) float32 copy of an (m, c, k) array: components as contiguous rows."""
    return np.ascontiguousarray(np.swapaxes(np.asarray(A, dtype=np.float32), 1, 2))


def _rotation_rows(q):
    """Rotation matrices of unit quaternions q (4, t) (w, x, y, z) as a 3 x 3 nested list of
    (t,) rows: R[i][j] is entry (i, j) of every tet's rotation."""
    w, x, y, z = q
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    return [[1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
            [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
            [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)]]


def _best_rotation(P, Q):
    """Rotation R minimising sum |R (p - mean p) - (q - mean q)|^2 (Kabsch)."""
    H = (P - P.mean(axis=0)).T @ (Q - Q.mean(axis=0))
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def _rest_frames(t):
    return np.broadcast_to(np.eye(3), (t, 3, 3))


def _stacked(F):
    return np.ascontiguousarray(np.swapaxes(F, 1, 2)).reshape(-1, 3)


def anchored_offset(delta, dispersion, floor=1e-3):
    """Translation placing a non-linear blend relative to the linear blend of the same frames.

    Parameters
    ----------
    delta : (n, 3) float array       per-vertex offsets, non-linear minus linear
    dispersion : (n,) float array    how much the sources disagree on the rotation at each vertex
                                     (weighted quaternion variance, 0 = all rotate alike)
    floor : float                    dispersion below which vertices count as fully rigid

    Returns
    -------
    t : (3,) float array   weighted mean of ``delta``, weights 1 / (floor + dispersion)

    Notes
    -----
    The solve fixes the blend's shape up to a translation. Anchoring it where the sources agree
    on the rotation (the torso of a walk and a jog) makes non-linear and linear blends coincide
    there and leaves the difference in the parts that rotate (the limbs), so hybrid corrections
    stay sparse. When every part rotates alike (a rigid rotation), the weights are uniform and
    the centroids coincide, which places a rotation-interpolated rigid body exactly.
    """
    weight = 1.0 / (floor + dispersion)
    return (weight @ delta) / weight.sum()


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
    """

    def __init__(self, embedding, quaternions, stretch, detail, surfaces):
        self.embedding = embedding
        self.quaternions, self.stretch, self.detail = quaternions, stretch, detail  # as given
        # Component-major copies, (m, 4, t), (m, 6, t), (m, 3, n): every per-tet step of a blend
        # is then a pass over contiguous length-t rows (2-3x faster than (t, 4) records).
        self._q = _component_major(quaternions)
        self._s = _component_major(stretch)
        self._d = _component_major(detail)
        self.surfaces = surfaces
        self.solver = DeformationSolver(embedding.V_tet, embedding.T)
        self.B = embedding.B.tocsr()
        self.surface_tet = np.asarray(embedding.surface_tet)
        t = len(embedding.T)
        self._FT = np.empty((t, 3, 3))
        self._X = np.empty((len(embedding.V_tet), 3))
        self._recent = OrderedDict()

    def _parts(self, coefficients, frames):
        """Per-tet gradients F (t, 3, 3), surface detail term, linear surface and per-tet
        rotation dispersion of one blend of decomposed frames (everything before the solve).

        The last few are kept: a player at fixed weights asks for the same phase sample on
        consecutive frames (as one end of the interval, then the other)."""
        coefficients = np.asarray(coefficients, dtype=np.float64)
        frames = np.asarray(frames)
        key = (coefficients.tobytes(), frames.astype(np.int64).tobytes())
        parts = self._recent.get(key)
        if parts is None:
            parts = self._recent[key] = self._compute_parts(coefficients, frames)
            while len(self._recent) > 4:
                self._recent.popitem(last=False)
        return parts

    def _compute_parts(self, coefficients, frames):
        keep = coefficients != 0
        coefficients, frames = coefficients[keep], frames[keep]
        if len(frames) == 0:
            raise ValueError("blend weights are all zero")
        # Blend in the stored precision (float32) and convert only the per-tet results.
        c32 = coefficients.astype(np.float32)
        q = self._q[frames]  # (c, 4, t)
        top = q[int(np.argmax(coefficients))]
        signed = np.where(np.einsum("ckt,kt->ct", q, top) < 0, -c32[:, None], c32[:, None])
        qb = np.einsum("ct,ckt->kt", signed, q).astype(np.float64)  # (4, t)
        qb /= np.sqrt(np.einsum("kt,kt->t", qb, qb))
        agreement = np.einsum("ckt,kt->ct", q, qb.astype(np.float32))
        agreement *= agreement  # cos^2 of half the angle to the blend
        dispersion = 1.0 - c32 @ agreement
        R = _rotation_rows(qb)
        s = np.tensordot(c32, self._s[frames], axes=1).astype(np.float64)  # (6, t)
        S = [[None] * 3 for _ in range(3)]
        for c, (i, j) in enumerate(SYMMETRIC):
            S[i][j] = S[j][i] = s[c]
        # the solver's layout: FT[k] = (R S)^T of tet k
        FT = np.empty((qb.shape[1], 3, 3))
        for i in range(3):
            for j in range(3):
                FT[:, j, i] = R[i][0] * S[0][j] + R[i][1] * S[1][j] + R[i][2] * S[2][j]
        d = np.tensordot(c32, self._d[frames], axes=1)  # (3, n)
        tets = self.surface_tet
        detail = np.empty((d.shape[1], 3))
        for i in range(3):
            detail[:, i] = R[i][0][tets] * d[0] + R[i][1][tets] * d[1] + R[i][2][tets] * d[2]
        linear = np.tensordot(c32, self.surfaces[frames], axes=1)
        return FT, detail, linear, dispersion

    def blend_frames(self, coefficients, frames, out=None, *, then=None, a=0.0):
        """Blend decomposed frames ``frames`` (indices) with ``coefficients`` (summing to 1).

        With ``then = (coefficients, frames)`` and ``a`` in (0, 1), the result is (1 - a) times
        the first blend plus ``a`` times the second, computed with one solve (the solve is
        linear in the gradients); the placement offset uses the interpolated dispersion.

        Returns
        -------
        V : (n, 3) float array   blended surface
        """
        FT, detail, linear, dispersion = self._parts(coefficients, frames)
        if then is not None and a != 0.0:
            FT1, detail1, linear1, dispersion1 = self._parts(*then)
            np.multiply(FT1, a, out=self._FT)
            self._FT += (1.0 - a) * FT
            detail = (1.0 - a) * detail + a * detail1
            linear = (1.0 - a) * linear + a * linear1
            dispersion = (1.0 - a) * dispersion + a * dispersion1
        else:
            self._FT[...] = FT
        X = self.solver.solve(self._FT.reshape(-1, 3), out=self._X)
        surface = self.B @ X
        surface += detail
        surface -= anchored_offset(surface - linear, dispersion[self.surface_tet])
        if out is not None:
            out[...] = surface
            return out
        return surface


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


def decompose_frames(decomposer, frames, progress=None):
    """Decompose (m, n, 3) surface frames; returns stacked float32 (quaternions, stretch, detail)."""
    m = len(frames)
    first = decomposer.decompose(frames[0])
    q = np.empty((m,) + first.quaternions.shape, dtype=np.float32)
    s = np.empty((m,) + first.stretch.shape, dtype=np.float32)
    d = np.empty((m,) + first.detail.shape, dtype=np.float32)
    for i in range(m):
        dec = first if i == 0 else decomposer.decompose(frames[i])
        q[i], s[i], d[i] = dec.quaternions, dec.stretch, dec.detail
        if progress is not None:
            progress(i + 1, m)
    return q, s, d


__all__ = ["VolumetricEmbedding", "FrameDecomposer", "FrameDecomposition", "NonlinearBlender",
           "decompose_frames", "anchored_offset"]

"""Source frames in blendable form: the volumetric embedding and the per-frame decomposition
(Casas et al. 2012, section 4.1), done once per source frame when a space is built.

The rest surface is embedded in a tetrahedral mesh (``VolumetricEmbedding``). Each source frame
is decomposed (``FrameDecomposer``): the tet vertices are fitted to the frame's surface, each
tet's deformation gradient is split by polar decomposition into a rotation (quaternion) and a
symmetric stretch, and what the embedded tet mesh does not reproduce of the surface (its fine
detail) is stored per vertex in the local frame of its tet's rotation. ``NonlinearBlender``
(``engine.blend.nonlinear``) blends the decompositions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from engine.deform import DeformationSolver
from engine.tetmesh import (
    deformation_gradients,
    polar_decomposition,
    rest_inverse,
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

    @property
    def surface_share(self):
        """(n,) float array or None: each surface vertex's share of its place.

        Vertices embedded alike (the same tet and coordinates: copies of one point, as an unwelded
        triangle soup or a mesh split at its texture seams keeps them) share one place, each
        counting 1 / copies in the fits and placements, so a surface weighs the same however
        often its file repeats a point. None when no two vertices share a place (every weight 1).
        """
        keys = np.column_stack([self.surface_tet.astype(np.float64), self.surface_bary])
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        if len(counts) == len(keys):
            return None
        return 1.0 / counts[inverse.reshape(-1)]


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
    interior tets follow the surface rigidly where they can. What the tets do not follow is
    the frame's detail, given back exactly. The default weight (3; it was 30) keeps the tets
    from being forced onto surfaces that touch or press into each other (a knee to the chest,
    hands on hips), where a stiff fit inverted up to 3% of the tets and their blends swelled:
    studio frames blended 50/50 kept their capped volume within 0.49% instead of 2.9%
    (``benchmarks/open_blends.py``).
    """

    def __init__(self, embedding, *, fit_weight=3.0, iterations=2):
        self.embedding = embedding
        self.fit_weight = float(fit_weight)
        self.B = embedding.B
        L = tet_laplacian(embedding.V_tet, embedding.T)
        self.weight = float(np.sqrt(fit_weight * L.diagonal().mean()))
        # copies of one point (a triangle soup) count once together: the fit, and so the blend,
        # is the welded surface's
        self.share = embedding.surface_share
        weight = self.weight if self.share is None else self.weight * np.sqrt(self.share)
        self.solver = DeformationSolver(embedding.V_tet, embedding.T, constraints=self.B,
                                        constraint_weight=weight)
        self.iterations = int(iterations)
        self.rest_surface = np.asarray(self.B @ embedding.V_tet)
        # a solid in several parts (a floating piece filled on its own) starts each part from
        # its own surface's best rotation: one rotation for all would leave a piece that turns
        # apart from the body to the ARAP steps, which do not get there
        T = np.asarray(embedding.T)
        self._rest_inverse = rest_inverse(embedding.V_tet, T)  # every fit's gradients share it
        self._tet_part = self.solver.part[T[:, 0]] if self.solver.n_parts > 1 else None
        if self._tet_part is not None:
            self._surface_part = self.solver.part[T[np.asarray(embedding.surface_tet), 0]]

    def _start_rotations(self, S):
        """Every tet's first target: the best rotation of the surface (of its part's surface)."""
        t = len(self.embedding.T)
        share = self.share
        if self._tet_part is None:
            return np.broadcast_to(_best_rotation(self.rest_surface, S, share), (t, 3, 3))
        R = np.empty((self.solver.n_parts, 3, 3))
        for part in range(self.solver.n_parts):
            held = self._surface_part == part
            R[part] = (_best_rotation(self.rest_surface[held], S[held], None if share is None else share[held])
                       if held.sum() >= 3 else np.eye(3))
        return R[self._tet_part]

    def fit(self, S):
        """Tet vertex positions (k, 3) fitted to surface frame S (n, 3)."""
        T, V_tet = self.embedding.T, self.embedding.V_tet
        X = self.solver.solve(_stacked(self._start_rotations(S)), S)
        for _ in range(self.iterations):
            R, _ = polar_decomposition(deformation_gradients(V_tet, X, T, rest_inverse=self._rest_inverse))
            X = self.solver.solve(_stacked(R), S)  # the rest frames are the identity: R itself
        return X

    def decompose(self, S):
        """Fit the tet mesh to S and split it into rotations, stretches and local detail."""
        S = np.asarray(S, dtype=np.float64)
        emb = self.embedding
        X = self.fit(S)
        F = deformation_gradients(emb.V_tet, X, emb.T, rest_inverse=self._rest_inverse)
        R, Sy = polar_decomposition(F)
        q = rotations_to_quaternions(R)
        residual = S - self.B @ X
        R_surface = R[emb.surface_tet]
        detail = np.einsum("nba,nb->na", R_surface, residual)  # R^T r
        return FrameDecomposition(quaternions=q, stretch=_stretch_to_vector(Sy), detail=detail)


def _best_rotation(P, Q, weight=None):
    """Rotation R minimising sum w |R (p - mean p) - (q - mean q)|^2 (Kabsch; weights w, else 1)."""
    if weight is None:
        H = (P - P.mean(axis=0)).T @ (Q - Q.mean(axis=0))
    else:
        w = weight / weight.sum()
        H = (w[:, None] * (P - w @ P)).T @ (Q - w @ Q)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def _stacked(F):
    return np.ascontiguousarray(np.swapaxes(F, 1, 2)).reshape(-1, 3)


def decompose_frames(decomposer, frames, progress=None, runner=None, chunk=None):
    """Decompose (m, n, 3) surface frames; returns stacked float32 (quaternions, stretch, detail).

    With ``runner`` (:mod:`engine.tasks`), chunks of ``chunk`` frames are decomposed as its tasks,
    each where the runner puts it (the decomposer is set up once per worker thread); the same result.
    ``chunk`` defaults to about m / 16 frames, at most 16: at least 16 tasks when there are
    that many frames, so the work spreads over the workers and progress comes in small steps.
    """
    m = len(frames)
    if chunk is None:
        chunk = min(16, max(1, -(-m // 16)))
    if runner is not None and m:
        from engine.tasks import Rebuilt

        shared = Rebuilt(_decomposer, (decomposer.embedding, decomposer.fit_weight, decomposer.iterations),
                         value=decomposer)
        chunks = [np.asarray(frames[i:i + chunk]) for i in range(0, m, chunk)]
        parts = runner.map(decompose_task, chunks, shared=shared, sizes=[len(c) for c in chunks], progress=progress)
        return tuple(np.concatenate([part[k] for part in parts]) for k in range(3))
    from engine.tasks import checkpoint

    first = decomposer.decompose(frames[0])
    q = np.empty((m,) + first.quaternions.shape, dtype=np.float32)
    s = np.empty((m,) + first.stretch.shape, dtype=np.float32)
    d = np.empty((m,) + first.detail.shape, dtype=np.float32)
    for i in range(m):
        checkpoint()  # a task stops here when its runner says the work has ended
        dec = first if i == 0 else decomposer.decompose(frames[i])
        q[i], s[i], d[i] = dec.quaternions, dec.stretch, dec.detail
        if progress is not None:
            progress(i + 1, m)
    return q, s, d


def _decomposer(embedding, fit_weight, iterations):
    return FrameDecomposer(embedding, fit_weight=fit_weight, iterations=iterations)


def decompose_task(shared, frames):
    """Runner task: ``decompose_frames`` of a chunk of frames with the shared decomposer."""
    from engine.tasks import shared_value

    return decompose_frames(shared_value(shared), frames)


__all__ = ["SYMMETRIC", "VolumetricEmbedding", "FrameDecomposition", "FrameDecomposer", "decompose_frames",
           "decompose_task"]

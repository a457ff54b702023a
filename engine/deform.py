"""Prefactored soft-constrained volumetric Laplacian solves (Casas et al. 2012, eq. 2).

``solver = DeformationSolver(V_tet, T, constraints, constraint_weight)`` builds and factors
the normal equations once; ``X = solver.solve(target_gradients, constraint_positions)`` is
the cheap hot-path call (one sparse product and one triangular solve pair for all three
coordinates). ``DeformationSolver(V_tet, T)`` (no constraints) is the variant for blending,
where only the shape is prescribed and the translation is fixed by a centroid.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import connected_components

from .tetmesh import tet_gradient, tet_volumes

try:  # optional: a faster sparse Cholesky for repeated solves
    import cholespy
except ImportError:  # pragma: no cover - depends on the environment
    cholespy = None

BACKENDS = ("auto", "cholespy", "scipy")


def stacked_gradients(F):
    """Per-tet deformation gradients as the (3t, 3) target of :meth:`DeformationSolver.solve`.

    Parameters
    ----------
    F : (t, 3, 3) float array   e.g. blended ``R @ S`` per tet

    Returns
    -------
    g : (3t, 3) float64 array   rows ``3*i .. 3*i + 2`` hold ``F[i].T``, matching the row
                                order of ``tet_gradient`` (so ``G @ X == g`` when ``X``
                                deforms the rest mesh by ``F``)
    """
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise ValueError(f"F must have shape (t, 3, 3), got {F.shape}")
    return np.ascontiguousarray(np.swapaxes(F, 1, 2)).reshape(-1, 3)


class DeformationSolver:
    """Least-squares vertex positions from target per-tet gradients and soft constraints.

    Minimises ``||G X - g||_D^2 + ||W (B X - X_c)||^2`` over the tet vertex positions ``X``
    (k, 3), all three coordinates at once, through the normal equations
    ``A X = G^T D g + B^T W^2 X_c`` with ``A = G^T D G + B^T W^2 B = L + B^T W^2 B``,
    symmetric positive definite and factored once here.

    Parameters
    ----------
    V_tet : (k, 3) float array   rest tet-mesh vertices (the gradients are taken here)
    T : (t, 4) int array         tetrahedra
    constraints : (c,) int array of vertex indices, or (c, k) scipy.sparse matrix, or None
        Rows of ``B``: constrained vertices, or linear combinations of them (e.g. the rows
        of ``embed_barycentric`` to constrain surface points). ``None`` gives the
        unconstrained variant: the solution is unique up to a translation of each connected
        part, which :meth:`solve` fixes by placing the volume centroids (one part: its
        centroid; several: each part's centroid where it rests, all moved as one).
    constraint_weight : float or (c,) float array
        The diagonal of ``W``, > 0. ``L``'s diagonal is of the order of the local edge
        length (metres); a weight whose square is much larger than ``L.diagonal().mean()``
        makes the constraints nearly hard. Ignored without constraints.
    backend : {"auto", "cholespy", "scipy"}
        Sparse factorisation: ``cholespy`` (Cholesky, the fastest repeated solves) when
        installed and ``"auto"``, otherwise SciPy's SuperLU.

    Attributes
    ----------
    G : (3t, k) csr_matrix     gradient operator (rows 3i..3i+2: d/dx, d/dy, d/dz in tet i)
    L : (k, k) csr_matrix      ``G^T D G``
    volumes : (t,) float array  tet volumes, the diagonal of ``D`` (each repeated 3 times)
    backend : str              the factorisation in use, "cholespy" or "scipy"
    n_vertices, n_tets, n_constraints : int
    n_parts : int              connected parts of the tet mesh (an unused vertex counts as one)
    part : (k,) int array      the part of each tet vertex

    Raises
    ------
    ValueError
        Bad shapes, indices or weights; a connected part of the tet mesh with no constraint
        (the system would be singular).

    Notes
    -----
    Casas et al. 2012, eq. (2), in its gradient form: ``L = G^T D G`` (section 3.2, their
    refs [1, 35]) and targets ``g`` in place of ``delta(x_0)``. With ``g = G X_0`` for an
    affine or rigid copy ``X_0`` of the rest mesh and consistent ``X_c`` both terms vanish,
    so the solve returns ``X_0`` exactly. The non-linear blend (section 4.1) supplies
    blended ``R S`` per tet as ``g`` (see :func:`stacked_gradients`).

    Cost: for a 3,700-vertex, 12,700-tet body mesh, building takes about 30 ms and a solve
    about 0.4 ms on one core with cholespy (0.6 ms with SuperLU), half of it the product
    ``G^T D g``. :meth:`solve` reuses an internal buffer, so one solver must not be shared
    between threads; the factor cannot be pickled, build the solver where it is used.
    """

    def __init__(self, V_tet, T, constraints=None, constraint_weight=1.0, *, backend="auto"):
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if backend == "cholespy" and cholespy is None:
            raise ValueError("backend='cholespy' but the cholespy package is not installed")
        self.G = tet_gradient(V_tet, T)  # validates V_tet and T
        V_tet, T = np.asarray(V_tet, dtype=np.float64), np.asarray(T, dtype=np.int64)
        if len(T) == 0:
            raise ValueError("T has no tetrahedra")
        k = len(V_tet)
        self.n_vertices, self.n_tets = k, len(T)
        self.volumes = np.abs(tet_volumes(V_tet, T))
        GtD = (self.G.T @ sp.diags(np.repeat(self.volumes, 3))).tocsr()
        self.L = (GtD @ self.G).tocsr()
        self.L = (0.5 * (self.L + self.L.T)).tocsr()
        self._GtD = GtD.tocsc()  # CSC: the (k, 3t) @ (3t, 3) product is about 2x faster

        n_parts, part = connected_components(self.L, directed=False)
        self.n_parts, self.part = int(n_parts), part.astype(np.int64)
        if constraints is None:
            # Pin one vertex of every connected part softly (its first): it removes each part's
            # translational null space without changing the shape of the minimiser (the pin term
            # is zero after a translation). A solid in several parts (a surface with a floating
            # piece, a body with separate eyes) then has each part placed by its own centroid.
            self._free = True
            pins = np.unique(self.part, return_index=True)[1]
            self._pin_target = V_tet[pins].copy()
            B = sp.csr_matrix((np.ones(len(pins)), (np.arange(len(pins)), pins)), shape=(len(pins), k))
            weight2 = np.full(len(pins), self.L.diagonal().mean())
            lumped = np.zeros(k)
            np.add.at(lumped, T.ravel(), np.repeat(self.volumes / 4.0, 4))
            self._centroid_weights = lumped / lumped.sum()
            self._rest_centroid = self._centroid_weights @ V_tet
            if self.n_parts > 1:
                # each part's own centroid weights, and where its centroid rests (an unused
                # vertex is a part of no volume: it keeps its rest place)
                mass = np.bincount(self.part, weights=lumped, minlength=self.n_parts)
                self._part_weights = lumped / np.where(mass > 0, mass, 1.0)[self.part]
                self._part_weights[mass[self.part] == 0] = 1.0
                self._part_rest = self._part_centroids(V_tet)
        else:
            self._free = False
            B = _constraint_matrix(constraints, k)
            weight = np.asarray(constraint_weight, dtype=np.float64)
            if weight.shape not in ((), (B.shape[0],)):
                raise ValueError(f"constraint_weight must be a scalar or have shape ({B.shape[0]},), "
                                 f"got {weight.shape}")
            if not np.all(np.isfinite(weight) & (weight > 0)):
                raise ValueError("constraint_weight must be finite and > 0")
            weight2 = np.broadcast_to(weight**2, (B.shape[0],))
            entries = B.tocoo()
            touched = np.zeros(k, dtype=bool)
            touched[entries.col[entries.data != 0]] = True
            loose = np.setdiff1d(np.arange(n_parts), part[touched])
            if len(loose):
                raise ValueError(f"{len(loose)} of {n_parts} connected parts of the tet mesh have "
                                 "no constraint; the system would be singular")
        self.n_constraints = 0 if self._free else B.shape[0]
        self._BtW2 = (B.T @ sp.diags(weight2)).tocsr()
        A = (self.L + self._BtW2 @ B).tocsr()
        A = (0.5 * (A + A.T)).tocsr()
        A.sum_duplicates()
        self.backend = "cholespy" if backend == "cholespy" or (backend == "auto" and cholespy) else "scipy"
        if self.backend == "cholespy":
            A = A.tocoo()
            self._factor = cholespy.CholeskySolverD(
                k, A.row.astype(np.int32), A.col.astype(np.int32),
                np.ascontiguousarray(A.data), cholespy.MatrixType.COO)
        else:
            self._factor = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A",
                                     options={"SymmetricMode": True})
        self._rhs = np.empty((k, 3))
        self._GtD_components = None  # built by the first solve_components
        self._pin_rhs = None if not self._free else self._BtW2 @ self._pin_target

    def solve(self, target_gradients, constraint_positions=None, *, centroid=None, out=None):
        """Vertex positions whose per-tet gradients best match the targets.

        Parameters
        ----------
        target_gradients : (3t, 3) float array
            Rows ``3*i .. 3*i + 2`` are the transposed target deformation gradient of tet
            ``i`` (see :func:`stacked_gradients`); the rest mesh has ``G @ V_tet``.
        constraint_positions : (c, 3) float array
            Targets ``X_c`` of the constraint rows; required with constraints, must be
            ``None`` without.
        centroid : (3,) float array, optional
            Unconstrained solver only: where to put the volume centroid of the result
            (default: the rest mesh's). A tet mesh in several parts keeps each part's
            centroid where it rests relative to the others, and moves them together.
        out : (k, 3) float64 C-contiguous array, optional
            Written in place and returned (no allocation for the result).

        Returns
        -------
        X : (k, 3) float64 array   tet vertex positions
        """
        g = np.asarray(target_gradients, dtype=np.float64)
        if g.shape != (3 * self.n_tets, 3):
            raise ValueError(f"target_gradients must have shape ({3 * self.n_tets}, 3), got {g.shape}")
        rhs = self._rhs
        rhs[...] = self._GtD @ g
        if self._free:
            if constraint_positions is not None:
                raise ValueError("this solver has no constraints; pass centroid=... instead")
            rhs += self._pin_rhs
        else:
            if centroid is not None:
                raise ValueError("centroid is only for the unconstrained solver")
            if constraint_positions is None:
                raise ValueError("constraint_positions are required: this solver has "
                                 f"{self.n_constraints} constraints")
            x_c = np.asarray(constraint_positions, dtype=np.float64)
            if x_c.shape != (self.n_constraints, 3):
                raise ValueError(f"constraint_positions must have shape ({self.n_constraints}, 3), "
                                 f"got {x_c.shape}")
            rhs += self._BtW2 @ x_c
        return self._solve_rhs(rhs, centroid, out)

    def _solve_rhs(self, rhs, centroid, out):
        """A^{-1} rhs into ``out``; the unconstrained solver then places the centroid."""
        if out is None:
            out = np.empty((self.n_vertices, 3))
        elif out.shape != (self.n_vertices, 3) or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous float64 array of shape ({self.n_vertices}, 3)")
        if self.backend == "cholespy":
            self._factor.solve(rhs, out)
        else:
            out[...] = self._factor.solve(rhs)
        if self._free:
            target = self._rest_centroid if centroid is None else np.asarray(centroid, dtype=np.float64)
            if target.shape != (3,):
                raise ValueError(f"centroid must have shape (3,), got {target.shape}")
            if self.n_parts > 1:   # every part's centroid where it rests, then all moved as one
                out += (self._part_rest - self._part_centroids(out))[self.part]
                out += target - self._rest_centroid
            else:
                out += target - self._centroid_weights @ out
        return out

    def _part_centroids(self, X):
        """(n_parts, 3) volume centroid of each connected part of X."""
        return np.stack([np.bincount(self.part, weights=self._part_weights * X[:, c], minlength=self.n_parts)
                         for c in range(3)], axis=1)

    def solve_components(self, F, *, centroid=None, out=None):
        """:meth:`solve` for the unconstrained solver with the targets given component-major.

        Parameters
        ----------
        F : (3, 3, t) float64 C-contiguous array
            ``F[i, j]`` is entry (i, j) of every tet's target deformation gradient (the same
            targets as ``solve(stacked_gradients(F.transpose(2, 0, 1)))``). This is the layout
            a blend computes in (one contiguous row per entry), so the (t, 3, 3) interleaving
            copy is never made: ``G^T D g`` is three sparse products with the gradient
            operator's columns permuted to match.
        centroid, out : as for :meth:`solve`

        Returns
        -------
        X : (k, 3) float64 array   tet vertex positions, equal to :meth:`solve`'s to rounding
        """
        if not self._free:
            raise ValueError("solve_components is for the unconstrained solver")
        F = np.asarray(F, dtype=np.float64)
        if F.shape != (3, 3, self.n_tets) or not F.flags.c_contiguous:
            raise ValueError(f"F must be a C-contiguous (3, 3, {self.n_tets}) array, got {F.shape}")
        if self._GtD_components is None:
            t = self.n_tets
            # column j * t + i of the permuted operator is column 3 i + j of G^T D
            order = (3 * np.arange(t)[None, :] + np.arange(3)[:, None]).ravel()
            self._GtD_components = self._GtD.tocsr()[:, order].tocsr()
        rows = F.reshape(3, -1)
        rhs = self._rhs
        for i in range(3):
            rhs[:, i] = self._GtD_components @ rows[i]
        rhs += self._pin_rhs
        return self._solve_rhs(rhs, centroid, out)


def _constraint_matrix(constraints, k):
    """(c, k) csr_matrix ``B`` from vertex indices or a sparse matrix."""
    if sp.issparse(constraints):
        B = sp.csr_matrix(constraints, dtype=np.float64)
        if B.shape[1] != k or B.shape[0] == 0:
            raise ValueError(f"constraint matrix must have shape (c >= 1, {k}), got {B.shape}")
        if not np.all(np.isfinite(B.data)):
            raise ValueError("constraint matrix has non-finite entries")
        return B
    index = np.asarray(constraints)
    if index.ndim != 1 or len(index) == 0 or not np.issubdtype(index.dtype, np.integer):
        raise ValueError("constraints must be a non-empty 1-D integer array of vertex indices "
                         "or a scipy.sparse (c, k) matrix")
    if index.min() < 0 or index.max() >= k:
        raise ValueError(f"constraint indices must lie in 0..{k - 1}")
    return sp.csr_matrix((np.ones(len(index)), (np.arange(len(index)), index)), shape=(len(index), k))

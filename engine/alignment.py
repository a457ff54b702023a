"""Non-rigid pairwise alignment of meshes and its propagation along a tree (Casas et al. 2012, 3.2).

``aligner = PairwiseAligner(V_root, F_root, colors_root)`` does the expensive set-up once: it
fills the root mesh with tetrahedra, embeds the surface, builds the coarse-to-fine patch
partitions and prefactors the soft-constrained volumetric solves. The hot path,
``aligner.align(X_source, TargetSurface(V, F, colors))``, deforms the root mesh from a pose (its
tet vertices ``X_source``) onto another frame's unstructured surface:

1. rigid start: centroids, the rotation about the vertical axis suggested by the shape
   histograms, point-to-plane ICP;
2. coarse to fine, with about 30 patches doubling each level: every patch is matched rigidly
   to the target (closest points with compatible normals both ways, colour cues when both
   meshes carry vertex colours, robust weights, outlier rejection), and the patch-moved
   vertices become soft constraints of an as-rigid-as-possible volumetric solve (eq. 2 with
   the root's tet Laplacian ``L = G^T D G``; rotations re-estimated per tet);
3. per-vertex closest-point rounds, then the surface is projected onto the target.

:func:`align_tree` runs it from the root along the branches of a shape similarity tree (each
frame from its parent's result); :func:`align_sequential` is the frame-to-frame baseline.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from engine.deform import DeformationSolver
from engine.rotations import axis_angle_matrix, rot_y
from engine.shape_histogram import is_closed, shape_centre
from engine.surface import _closest_on_triangles, vertex_normals


@dataclass(frozen=True)
class AlignmentOptions:
    """Parameters of the pairwise aligner (defaults tuned on 3,000-vertex bodies).

    Attributes
    ----------
    patches : int               patches at the coarsest level (paper: 30), doubled per level
    levels : int                coarse-to-fine levels
    rounds : tuple of int       patch matching + deformation rounds, per level
    icp_steps : int             rigid ICP steps per patch and round
    arap_steps : int            local/global steps per deformation
    final_rounds : int          per-vertex closest-point rounds before the projection
    max_normal_angle : float    degrees; pairs with normals further apart are rejected
    neighbours : int            target vertices examined per correspondence
    stiffness : tuple of float  constraint weight^2 / mean Laplacian diagonal, per level
    final_stiffness : float     the same for the per-vertex rounds
    colour_sigma : float        RGB distance (0..1 per channel) at which colour cues fade
    colour_weight : float       tangential weight of colour cues (0 disables them)
    tangential_damping : float  weight keeping patches from sliding along the surface
    outlier_factor : float      pairs farther than this times the median distance are outliers
    rigid_iterations : int      ICP iterations of the rigid start
    rotation_prior : float      pull of each tet's rotation towards the source pose's
    search_levels : int         coarse levels whose patches also try articulated hypotheses
                                (rotations about the joint with the best-fitting neighbour,
                                the neighbours' motions) and keep the best fitting one
    search_rounds : int         rounds per such level that search
    search_angles : tuple       rotation angles tried about each axis (degrees, both signs)
    search_samples : int        vertices per patch used to score hypotheses
    search_cap : float          distance (m) at which a sample counts as unmatched
    tet_epsilon : float         fTetWild envelope (fraction of the bounding-box diagonal) when
                                the root is tetrahedralised here
    """

    patches: int = 30
    levels: int = 4
    rounds: tuple = (6, 3, 2, 1)
    icp_steps: int = 3
    arap_steps: int = 2
    final_rounds: int = 2
    max_normal_angle: float = 60.0
    neighbours: int = 8
    stiffness: tuple = (0.5, 2.0, 8.0, 30.0)
    final_stiffness: float = 100.0
    colour_sigma: float = 0.12
    colour_weight: float = 0.0
    tangential_damping: float = 0.05
    outlier_factor: float = 3.0
    rigid_iterations: int = 15
    rotation_prior: float = 0.0
    search_levels: int = 1
    search_rounds: int = 3
    search_angles: tuple = (30.0, 60.0, 90.0)
    search_samples: int = 24
    search_cap: float = 0.05
    tet_epsilon: float = 2e-3


@dataclass
class PairAlignment:
    """Result of one pairwise alignment.

    Attributes
    ----------
    V : (n, 3) float array      the root mesh's vertices on the target surface
    X : (k, 3) float array      tet vertices of the deformation (the start for children)
    residual : float            mean two-sided distance between V and the target surface (m)
    residual_max : float        the largest of those distances (m)
    distortion : float          volume-weighted mean of ||F - R||^2 over the tets (0 for a
                                rigid motion of the root; large when the fit tore or twisted)
    seconds : float
    """

    V: np.ndarray
    X: np.ndarray
    residual: float
    residual_max: float
    distortion: float = 0.0
    seconds: float = 0.0

    @property
    def quality(self):
        """A single badness score: distortion plus mean residual in units of 5 cm."""
        return self.distortion + self.residual / 0.05


class TargetSurface:
    """A frame's unstructured surface prepared for correspondence queries.

    Parameters
    ----------
    V : (m, 3) float array
    F : (l, 3) int array
    colors : (m, 3) float array in [0, 1] or None
    """

    def __init__(self, V, F, colors=None):
        self.V = np.ascontiguousarray(V, dtype=np.float64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        if self.V.ndim != 2 or self.V.shape[1] != 3 or len(self.V) < 4:
            raise ValueError(f"target vertices must have shape (m >= 4, 3), got {self.V.shape}")
        self.colors = None if colors is None else np.asarray(colors, dtype=np.float64)
        self.normals = vertex_normals(self.V, self.F)
        self.tree = cKDTree(self.V)
        self.face_centres = self.V[self.F].mean(axis=1)
        self.face_tree = cKDTree(self.face_centres)
        edges = self.V[self.F] - self.V[np.roll(self.F, 1, axis=1)]
        self.edge_length = float(np.mean(np.linalg.norm(edges, axis=2)))
        self.centre = shape_centre(self.V, self.F)

    def closest(self, P, k=6):
        """Closest points on the surface among the ``k`` faces with the nearest centres.

        Returns
        -------
        points : (q, 3) float array
        distance : (q,) float array
        faces : (q,) int array
        """
        P = np.asarray(P, dtype=np.float64)
        k = min(k, len(self.F))
        _, faces = self.face_tree.query(P, k=k)
        faces = faces.reshape(len(P), k)
        tri = self.V[self.F[faces.ravel()]]
        Pq = np.repeat(P, k, axis=0)
        points, _ = _closest_on_triangles(Pq, tri[:, 0], tri[:, 1], tri[:, 2])
        dist = np.linalg.norm(points - Pq, axis=1).reshape(len(P), k)
        best = np.argmin(dist, axis=1)
        pick = np.arange(len(P)) * k + best
        return points[pick], dist[np.arange(len(P)), best], faces[np.arange(len(P)), best]


def farthest_point_patches(V, F, counts, *, seed=0):
    """Nested surface partitions by farthest-point sampling over mesh-edge (geodesic) distance.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array
    counts : sequence of int    patch counts, increasing
    seed : int                  chooses the first sample

    Returns
    -------
    labels : list of (n,) int arrays   the patch of every vertex, one array per count
    """
    V = np.asarray(V, dtype=np.float64)
    n = len(V)
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    length = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1) + 1e-12
    graph = sp.csr_matrix((length, (edges[:, 0], edges[:, 1])), shape=(n, n))
    graph = graph.maximum(graph.T).tocsr()
    rng = np.random.default_rng(seed)
    most = min(int(max(counts)), n)
    seeds = [int(rng.integers(n))]
    nearest = dijkstra(graph, indices=seeds[0])
    nearest[~np.isfinite(nearest)] = np.inf
    # Unreachable parts (several components) are reached by restarting there.
    while len(seeds) < most:
        gap = np.where(np.isfinite(nearest), nearest, np.inf)
        candidate = int(np.argmax(gap))
        seeds.append(candidate)
        nearest = np.minimum(nearest, dijkstra(graph, indices=candidate))
    labels = []
    for count in counts:
        count = min(int(count), n)
        _, _, source = dijkstra(graph, indices=seeds[:count], min_only=True, return_predecessors=True)
        label_of = {s: i for i, s in enumerate(seeds[:count])}
        labels.append(np.array([label_of.get(int(s), 0) for s in source], dtype=np.int64))
    return labels


def _rodrigues(omega):
    """Rotation matrices (q, 3, 3) for rotation vectors (q, 3)."""
    return axis_angle_matrix(omega, np.linalg.norm(omega, axis=-1))


def rotation_fit(F, R0, iterations=4):
    """Rotations closest to matrices F, warm-started from R0 (batched).

    Parameters
    ----------
    F : (t, 3, 3) float array
    R0 : (t, 3, 3) float array   initial rotations (e.g. the previous step's)
    iterations : int

    Returns
    -------
    R : (t, 3, 3) float array

    Notes
    -----
    Müller, Bender, Chentanez, Macklin, "A robust method to extract the rotational part of
    deformations" (MIG 2016): ``omega = sum_i r_i x f_i / (|sum_i r_i . f_i| + eps)`` over the
    columns, ``R <- exp(omega) R``. Each step is a few vectorised products, far cheaper than a
    batched SVD, and a warm start needs only a few steps.
    """
    R = np.array(R0, dtype=np.float64, copy=True)
    for _ in range(iterations):
        cross = np.cross(R, F, axisa=1, axisb=1, axisc=1).sum(axis=2)  # sum over columns
        dot = np.einsum("tij,tij->t", R, F)
        omega = cross / (np.abs(dot) + 1e-9)[:, None]
        R = _rodrigues(omega) @ R
    return R


def _stack(R):
    return np.ascontiguousarray(np.swapaxes(R, 1, 2)).reshape(-1, 3)


def _kabsch(P, Q, w):
    """Weighted rigid transform (R, t) with R P + t ~ Q."""
    w = w / max(w.sum(), 1e-300)
    cp, cq = w @ P, w @ Q
    H = (P - cp).T @ ((Q - cq) * w[:, None])
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cq - R @ cp


class PairwiseAligner:
    """Deforms the root mesh (through its tet mesh) onto other frames' surfaces.

    Parameters
    ----------
    V : (n, 3) float array      root surface (closed, outward oriented): its vertices and faces
    F : (m, 3) int array        become every aligned frame's
    colors : (n, 3) float array or None   root vertex colours (colour cues when targets have them)
    tets : (V_tet, T) or None   a tet mesh of the root's solid (default: ``tetrahedralize``,
                                several seconds: pass a cached one)
    options : AlignmentOptions
    seed : int                  for the patch sampling

    Notes
    -----
    Casas et al. 2012, section 3.2: coarse-to-fine rigid patch matching (30 patches, doubling)
    feeding soft constraints to the tetrahedral Laplacian deformation of eq. (2). Here the
    per-tet rotations are re-estimated in local/global steps (as-rigid-as-possible) with the
    root's solid as the rest shape, so stretch never accumulates along the tree. The solves are
    prefactored, one per level: a per-vertex confidence ``c`` enters through the targets
    (``c * match + (1 - c) * current``), whose fixed point is the solve weighted by ``c``.
    """

    def __init__(self, V, F, colors=None, *, tets=None, options=None, seed=0):
        from engine.tetmesh import tet_barycentric, tet_gradient, tetrahedralize

        self.options = options or AlignmentOptions()
        self.seed = int(seed)
        self.V = np.ascontiguousarray(V, dtype=np.float64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        if not is_closed(self.F):
            raise ValueError("the root mesh must be a closed surface (it is filled with tetrahedra)")
        self.colors = None if colors is None else np.asarray(colors, dtype=np.float64)
        if tets is None:
            tets = tetrahedralize(self.V, self.F)
        self.V_tet = np.ascontiguousarray(tets[0], dtype=np.float64)
        self.T = np.ascontiguousarray(tets[1], dtype=np.int64)
        tet, bary, _ = tet_barycentric(self.V, self.V_tet, self.T)
        n = len(self.V)
        self.B = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(n), 4), self.T[tet].ravel())),
                               shape=(n, len(self.V_tet)))
        self.G = tet_gradient(self.V_tet, self.T)
        edges = self.V[self.F] - self.V[np.roll(self.F, 1, axis=1)]
        self.edge_length = float(np.mean(np.linalg.norm(edges, axis=2)))
        o = self.options
        counts = [min(n, o.patches * 2**level) for level in range(o.levels)]
        self.patch_counts = counts
        self.patch_labels = farthest_point_patches(self.V, self.F, counts, seed=seed)
        rng = np.random.default_rng(seed)
        self.patch_graph = [_patch_adjacency(self.F, labels, count)
                            for labels, count in zip(self.patch_labels, counts)]
        self.patch_samples = [_patch_samples(labels, count, o.search_samples, rng)
                              for labels, count in zip(self.patch_labels, counts)]
        self._search_rotations = _rotation_set(o.search_angles)
        probe = DeformationSolver(self.V_tet, self.T)
        self._tet_volume = probe.volumes
        scale = float(probe.L.diagonal().mean())
        weights = sorted(set(list(o.stiffness[:o.levels]) + [o.final_stiffness]))
        self._solvers = {w: DeformationSolver(self.V_tet, self.T, constraints=self.B,
                                              constraint_weight=np.sqrt(w * scale)) for w in weights}
        self._eye = np.broadcast_to(np.eye(3), (len(self.T), 3, 3))
        self._cos = np.cos(np.radians(o.max_normal_angle))

    # -- set-up helpers -------------------------------------------------------------------
    @property
    def n_vertices(self):
        return len(self.V)

    def surface(self, X):
        """Surface vertices (n, 3) carried by tet vertices X (k, 3)."""
        return self.B @ X

    def _gradients(self, X):
        return np.swapaxes((self.G @ X).reshape(-1, 3, 3), 1, 2)

    # -- hot path ----------------------------------------------------------------------------
    def align(self, X_source, target, *, yaw=None):
        """Deform the root mesh from pose ``X_source`` onto ``target``.

        Parameters
        ----------
        X_source : (k, 3) float array   tet vertices of the source pose (``aligner.V_tet`` for
                                        the root itself, or a previous result's ``X``)
        target : TargetSurface
        yaw : float or None             degrees about +Y that roughly turn the source onto the
                                        target (e.g. from the shape histograms); tried
                                        alongside no turn

        Returns
        -------
        PairAlignment
        """
        started = time.perf_counter()
        o = self.options
        X = self._rigid_start(np.asarray(X_source, dtype=np.float64), target, yaw)
        R = rotation_fit(self._gradients(X), self._eye, iterations=8)
        prior = R.copy()
        use_colour = self.colors is not None and target.colors is not None and o.colour_weight > 0
        for level in range(o.levels):
            labels, count = self.patch_labels[level], self.patch_counts[level]
            solver = self._solvers[o.stiffness[min(level, len(o.stiffness) - 1)]]
            for round_ in range(o.rounds[min(level, len(o.rounds) - 1)]):
                S = self.B @ X
                search = level < o.search_levels and round_ < o.search_rounds
                goal, confidence = self._match_patches(S, target, labels, count, use_colour,
                                                       level=level if search else None)
                X, R = self._deform(X, R, solver, goal, confidence, prior)
        solver = self._solvers[o.final_stiffness]
        for _ in range(o.final_rounds):
            S = self.B @ X
            goal, confidence = self._match_vertices(S, target, use_colour)
            X, R = self._deform(X, R, solver, goal, confidence, prior)
        S = self.B @ X
        V = self._project(S, target)
        residual, residual_max = self._residual(V, target)
        F = self._gradients(X)
        R = rotation_fit(F, R, iterations=4)
        distortion = float(self._tet_volume @ np.sum((F - R) ** 2, axis=(1, 2)) / self._tet_volume.sum())
        return PairAlignment(V=V, X=X, residual=residual, residual_max=residual_max, distortion=distortion,
                             seconds=time.perf_counter() - started)

    def _project(self, S, target):
        """Closest points of S on the target, except where that would fold or collapse faces.

        Vertices of faces whose normal turns by more than 60 degrees or whose area shrinks
        below a fifth keep their unprojected positions (a few millimetres off the surface).
        """
        V, _, _ = target.closest(S)
        before_n = np.cross(S[self.F[:, 1]] - S[self.F[:, 0]], S[self.F[:, 2]] - S[self.F[:, 0]])
        before_a = np.linalg.norm(before_n, axis=1)
        for _ in range(3):
            after_n = np.cross(V[self.F[:, 1]] - V[self.F[:, 0]], V[self.F[:, 2]] - V[self.F[:, 0]])
            after_a = np.linalg.norm(after_n, axis=1)
            cosine = np.einsum("fc,fc->f", before_n, after_n) / np.maximum(before_a * after_a, 1e-300)
            bad = (cosine < 0.5) | (after_a < 0.2 * before_a)
            if not bad.any():
                break
            keep = np.unique(self.F[bad])
            V[keep] = S[keep]
        return V

    def _residual(self, V, target):
        """Mean and max of the two-sided surface distance between aligned V and the target."""
        forward = target.closest(V)[1]
        backward = _point_to_mesh(target.V, V, self.F)
        both = np.concatenate([forward, backward])
        return float(both.mean()), float(both.max())

    def _rigid_start(self, X, target, yaw):
        """Best rigid motion of X onto the target, trying the hinted turn and none."""
        o = self.options
        S = self.B @ X
        centre = shape_centre(S, self.F, closed=True)
        rng = np.random.default_rng(0)
        sample = rng.choice(len(S), size=min(len(S), 600), replace=False)
        normals = vertex_normals(S, self.F)[sample]
        candidates = [0.0]
        if yaw is not None and np.isfinite(yaw) and abs(yaw) > 2.0:
            candidates.append(float(yaw))
        best = None
        for angle in candidates:
            R0 = rot_y(np.radians(angle))
            t0 = target.centre - R0 @ centre
            R, t = R0, t0
            for _ in range(o.rigid_iterations):
                P = S[sample] @ R.T + t
                N = normals @ R.T
                q, m, d, ok = self._nearest_compatible(P, N, target)
                limit = max(o.outlier_factor * np.median(d[ok]) if ok.any() else np.inf, 2 * target.edge_length)
                w = (ok & (d < limit)).astype(float)
                if w.sum() < 6:
                    break
                dR, dt = _point_to_plane_step(P, q, m, w)
                R, t = dR @ R, dR @ t + dt
            P = S[sample] @ R.T + t
            d = target.closest(P)[1]
            score = float(np.mean(np.minimum(d, np.percentile(d, 90))))
            if best is None or score < best[0]:
                best = (score, R, t)
        _, R, t = best
        return X @ R.T + t

    def _nearest_compatible(self, P, N, target):
        """Per point: the nearest target vertex with a compatible normal, projected to its plane.

        Returns
        -------
        q : (p, 3) foot of P on that vertex's tangent plane
        m : (p, 3) its normal
        d : (p,) distance to the vertex
        ok : (p,) bool, False when none of the nearest vertices is compatible
        """
        k = min(self.options.neighbours, len(target.V))
        d, idx = target.tree.query(P, k=k)
        d, idx = d.reshape(len(P), k), idx.reshape(len(P), k)
        compatible = np.einsum("pkc,pc->pk", target.normals[idx], N) > self._cos
        masked = np.where(compatible, d, np.inf)
        j = np.argmin(masked, axis=1)
        rows = np.arange(len(P))
        ok = np.isfinite(masked[rows, j])
        v, m = target.V[idx[rows, j]], target.normals[idx[rows, j]]
        q = P - np.einsum("pc,pc->p", P - v, m)[:, None] * m
        return q, m, d[rows, j], ok

    def _match_patches(self, S, target, labels, count, use_colour, level=None):
        """Rigidly match every patch to the target; returns per-vertex goals and confidences.

        With ``level`` given, badly fitting patches also try articulated hypotheses
        (:meth:`_search_patches`) after the ICP steps.
        """
        o = self.options
        x = S.copy()
        n = vertex_normals(S, self.F)
        size = np.bincount(labels, minlength=count).astype(float)
        for _ in range(o.icp_steps):
            y, m, w, tangential, d = self._pairs(x, n, target, use_colour, labels, count)
            # target -> source pairs pull the source into parts of the target it does not cover
            points, src, ys, ms, ws = self._reverse_pairs(x, n, target, labels, count)
            P = np.concatenate([x, points])
            Y = np.concatenate([y, ys])
            M = np.concatenate([m, ms])
            W = np.concatenate([w, ws])
            Tw = np.concatenate([tangential, np.zeros(len(src))])
            L = np.concatenate([labels, labels[src]])
            omega, shift, centres = _patch_steps(P, Y, M, W, Tw, L, count)
            Rp = _rodrigues(omega)
            x = np.einsum("pij,pj->pi", Rp[labels], x - centres[labels]) + centres[labels] + shift[labels]
            n = np.einsum("pij,pj->pi", Rp[labels], n)
        if level is not None:
            x, n = self._search_patches(x, n, target, level)
        y, m, w, tangential, d = self._pairs(x, n, target, use_colour, labels, count)
        support = np.bincount(labels, weights=w, minlength=count) / np.maximum(size, 1.0)
        confidence = np.clip(support[labels] * 1.25, 0.0, 1.0)
        return x, confidence

    def _sample_cost(self, P, N, target):
        """Robust fit cost per point: squared distance to the target, capped; incompatible = cap."""
        cap = self.options.search_cap
        q, m, d, ok = self._nearest_compatible(P, N, target)
        plane = np.abs(np.einsum("pc,pc->p", P - q, m))
        gap = np.where(ok, np.minimum(np.maximum(plane, 0.5 * d), cap), cap)
        return (gap / cap) ** 2

    def _search_patches(self, x, n, target, level):
        """Articulated hypotheses for every patch; the best fitting one (after ICP) wins.

        Hypotheses: the current pose, the motions of the neighbouring patches (as moved in
        this round relative to their start), and rotations about the joint with the
        best-fitting neighbour (the centre of their shared border) by the search angles about
        the three axes. Each is refined by point-to-plane ICP on a few samples and scored by
        its capped fit cost plus how far it tears the joint open.
        """
        o = self.options
        labels, count = self.patch_labels[level], self.patch_counts[level]
        samples, sample_patch = self.patch_samples[level]
        pairs, border = self.patch_graph[level]
        cost = np.bincount(sample_patch, weights=self._sample_cost(x[samples], n[samples], target),
                           minlength=count) / np.maximum(np.bincount(sample_patch, minlength=count), 1)
        bad = np.flatnonzero(cost > 0.05)
        if len(bad) == 0 or len(pairs) == 0:
            return x, n
        # joints: the centre of each shared border, at the current positions
        joint = np.stack([np.bincount(border[:, 2], weights=x[border[:, 0], a], minlength=len(pairs))
                          for a in range(3)], axis=1) / np.maximum(np.bincount(border[:, 2], minlength=len(pairs)), 1)[:, None]
        hyp_patch, hyp_R, hyp_c = [], [], []
        rotations = self._search_rotations
        for p in bad:
            touching = np.flatnonzero((pairs[:, 0] == p) | (pairs[:, 1] == p))
            if len(touching) == 0:
                continue
            other = np.where(pairs[touching, 0] == p, pairs[touching, 1], pairs[touching, 0])
            anchor = touching[np.argmin(cost[other])]
            hyp_patch.append(np.full(len(rotations) + 1, p))
            hyp_R.append(np.concatenate([np.eye(3)[None], rotations]))
            hyp_c.append(np.repeat(joint[anchor][None], len(rotations) + 1, axis=0))
        if not hyp_patch:
            return x, n
        hyp_patch = np.concatenate(hyp_patch)
        hyp_R = np.concatenate(hyp_R)
        hyp_c = np.concatenate(hyp_c)
        H = len(hyp_patch)
        # sample points of each hypothesis
        order = np.argsort(sample_patch, kind="stable")
        starts = np.searchsorted(sample_patch[order], np.arange(count + 1))
        members = [samples[order[starts[p]:starts[p + 1]]] for p in range(count)]
        idx = np.concatenate([members[p] for p in hyp_patch])
        owner = np.repeat(np.arange(H), [len(members[p]) for p in hyp_patch])
        P = np.einsum("pij,pj->pi", hyp_R[owner], x[idx] - hyp_c[owner]) + hyp_c[owner]
        N = np.einsum("pij,pj->pi", hyp_R[owner], n[idx])
        R_total, t_total = hyp_R.copy(), hyp_c - np.einsum("hij,hj->hi", hyp_R, hyp_c)
        for _ in range(3):
            q, m, d, ok = self._nearest_compatible(P, N, target)
            w = (ok & (d < 2 * o.search_cap)).astype(float)
            omega, shift, centres = _patch_steps(P, q, m, w, np.full(len(P), o.tangential_damping), owner, H)
            Rs = _rodrigues(omega)
            P = np.einsum("pij,pj->pi", Rs[owner], P - centres[owner]) + centres[owner] + shift[owner]
            N = np.einsum("pij,pj->pi", Rs[owner], N)
            # compose: x -> Rs (R x + t - c) + c + s
            t_total = np.einsum("hij,hj->hi", Rs, t_total - centres) + centres + shift
            R_total = Rs @ R_total
        score = np.bincount(owner, weights=self._sample_cost(P, N, target), minlength=H)
        score /= np.maximum(np.bincount(owner, minlength=H), 1)
        tear = np.linalg.norm(np.einsum("hij,hj->hi", R_total, hyp_c) + t_total - hyp_c, axis=1)
        score += (tear / o.search_cap) ** 2 * 0.25
        x, n = x.copy(), n.copy()
        for p in np.unique(hyp_patch):
            mine = np.flatnonzero(hyp_patch == p)
            best = mine[np.argmin(score[mine])]
            if best == mine[0] or score[best] > cost[p] - 0.02:
                continue  # the current pose (refined) is as good
            vertices = np.flatnonzero(labels == p)
            x[vertices] = x[vertices] @ R_total[best].T + t_total[best]
            n[vertices] = n[vertices] @ R_total[best].T
        return x, n

    def _match_vertices(self, S, target, use_colour):
        """Per-vertex closest compatible points and robust confidences."""
        n = vertex_normals(S, self.F)
        y, m, w, tangential, d = self._pairs(S, n, target, use_colour)
        return y, w

    def _pairs(self, x, n, target, use_colour, labels=None, count=1):
        """Correspondences of source points x (normals n) on the target surface.

        The closest surface point (exact, among the faces with the nearest centres) when its
        normal is compatible, otherwise the foot on the tangent plane of the nearest compatible
        vertex; robust weights from the distances (outliers get 0).

        Returns
        -------
        y : (p, 3) target points        m : (p, 3) target normals there
        w : (p,) weights in [0, 1]      tangential : (p,) tangential weight (colour cues)
        d : (p,) distances
        """
        o = self.options
        y, d, face, bary = _closest_points(x, target.V, target.F, target.face_tree)
        m = np.einsum("pk,pkc->pc", bary, target.normals[target.F[face]])
        m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-12)
        ok = np.einsum("pc,pc->p", m, n) > self._cos
        if not ok.all():
            bad = np.flatnonzero(~ok)
            q, mq, dq, okq = self._nearest_compatible(x[bad], n[bad], target)
            y[bad], m[bad], d[bad], ok[bad] = q, mq, dq, okq
        w = _robust_weights(d, ok, labels, count, o.outlier_factor, 1.5 * target.edge_length)
        tangential = np.full(len(x), o.tangential_damping)
        if use_colour:
            flow, strength = self._colour_flow(y, m, face, bary, target)
            y = y + flow
            tangential = tangential + o.colour_weight * strength
        return y, m, w, tangential, d

    def _colour_flow(self, y, m, face, bary, target):
        """Tangential shift towards where the target shows each source vertex's colour.

        Candidates are the current match y (colour interpolated in its face), the nearest
        target vertices and the midpoints towards them; each is scored by its colour distance
        to the source vertex's (root) colour plus a distance penalty, and the best one wins if
        it beats y clearly. A match whose colour already agrees does not move, so uniform
        regions and exact matches get no shift.

        Returns
        -------
        flow : (p, 3) tangential shifts
        strength : (p,) in [0, 1)   how much better the chosen colour agrees than y's
        """
        o = self.options
        h = target.edge_length
        k = min(o.neighbours, len(target.V))
        dist, idx = target.tree.query(y, k=k)
        dist, idx = dist.reshape(len(y), k), idx.reshape(len(y), k)
        here = np.einsum("pk,pkc->pc", bary, target.colors[target.F[face]])
        there = target.colors[idx]
        points = np.concatenate([y[:, None, :], target.V[idx], 0.5 * (y[:, None, :] + target.V[idx])], axis=1)
        colours = np.concatenate([here[:, None, :], there, 0.5 * (here[:, None, :] + there)], axis=1)
        facing = np.einsum("pkc,pc->pk", target.normals[idx], m) > 0.5
        allowed = np.concatenate([np.ones((len(y), 1), dtype=bool), facing, facing], axis=1)
        sigma2 = o.colour_sigma ** 2
        score = (np.sum((colours - self.colors[:, None, :]) ** 2, axis=2) / sigma2
                 + np.sum((points - y[:, None, :]) ** 2, axis=2) / (2.0 * h * h))
        score = np.where(allowed, score, np.inf)
        best = np.argmin(score, axis=1)
        rows = np.arange(len(y))
        gain = score[:, 0] - score[rows, best]
        shift = points[rows, best] - y
        shift -= np.einsum("pc,pc->p", shift, m)[:, None] * m
        strength = gain / (gain + 1.0)
        return shift, strength

    def _reverse_pairs(self, x, n, target, labels=None, count=1):
        """Target vertices paired with their closest points on the current source surface.

        Returns
        -------
        points : (t, 3) source surface points    labels_from : (t,) a source vertex of each
        y : (t, 3) target vertices                m : (t, 3) target normals
        w : (t,) weights
        """
        o = self.options
        tree = cKDTree(x[self.F].mean(axis=1))
        points, d, face, bary = _closest_points(target.V, x, self.F, tree)
        normal = np.einsum("tk,tkc->tc", bary, n[self.F[face]])
        ok = np.einsum("tc,tc->t", normal, target.normals) > self._cos
        vertex = self.F[face, np.argmax(bary, axis=1)]
        w = _robust_weights(d, ok, None if labels is None else labels[vertex], count, o.outlier_factor,
                            1.5 * target.edge_length)
        return points, vertex, target.V, target.normals, 0.5 * w

    def _deform(self, X, R, solver, goal, confidence, prior=None):
        """ARAP local/global steps towards per-vertex goals with confidences in [0, 1].

        ``prior`` (t, 3, 3): the source pose's per-tet rotations; each local step takes the
        rotation closest to ``F + rotation_prior * prior``, so parts turn no more than the
        data asks for (a limb does not twist about its own axis for free).
        """
        c = np.clip(confidence, 0.0, 1.0)[:, None]
        mu = self.options.rotation_prior
        for _ in range(self.options.arap_steps):
            F = self._gradients(X)
            if prior is not None and mu > 0:
                F = F + mu * prior
            R = rotation_fit(F, R, iterations=3)
            current = self.B @ X
            X = solver.solve(_stack(R), c * goal + (1.0 - c) * current)
        return X, R


def _patch_adjacency(F, labels, count):
    """Adjacent patch pairs and their border vertices.

    Returns
    -------
    pairs : (e, 2) int array          patch pairs (a < b) that share mesh edges
    border : (b, 3) int array         (vertex, its patch, pair index): vertices on a shared border
    """
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    la, lb = labels[edges[:, 0]], labels[edges[:, 1]]
    cut = la != lb
    a, b = np.minimum(la[cut], lb[cut]), np.maximum(la[cut], lb[cut])
    code = a * count + b
    unique, pair_of = np.unique(code, return_inverse=True)
    pairs = np.stack([unique // count, unique % count], axis=1)
    verts = np.concatenate([edges[cut, 0], edges[cut, 1]])
    pair_index = np.concatenate([pair_of, pair_of])
    border = np.unique(np.stack([verts, labels[verts], pair_index], axis=1), axis=0)
    return pairs.astype(np.int64), border.astype(np.int64)


def _patch_samples(labels, count, per_patch, rng):
    """Up to ``per_patch`` random vertices of every patch: (indices, their patch)."""
    chosen = []
    for p in range(count):
        members = np.flatnonzero(labels == p)
        if len(members) > per_patch:
            members = np.sort(rng.choice(members, size=per_patch, replace=False))
        chosen.append(members)
    idx = np.concatenate(chosen)
    return idx, labels[idx]


def _rotation_set(angles):
    """Rotations by +-angle about the x, y and z axes (degrees): (6 * len(angles), 3, 3)."""
    rotations = []
    for axis in np.eye(3):
        for angle in angles:
            for sign in (1.0, -1.0):
                rotations.append(_rodrigues(np.radians(sign * angle) * axis[None])[0])
    return np.array(rotations)


def _robust_weights(d, ok, labels, count, factor, floor):
    """Tukey-style weights with an outlier limit of factor x the median distance per patch.

    Parameters
    ----------
    d : (p,) distances     ok : (p,) bool, pairs that passed the normal test
    labels : (p,) int patch of each pair, or None for one global limit
    count : int number of patches
    factor, floor : the limit is max(factor * median, floor)

    Returns
    -------
    w : (p,) float in [0, 1]
    """
    if labels is None:
        labels, count = np.zeros(len(d), dtype=np.int64), 1
    median = np.full(count, np.inf)
    good = np.flatnonzero(ok)
    if len(good):
        order = good[np.lexsort((d[good], labels[good]))]
        lab = labels[order]
        starts = np.searchsorted(lab, np.arange(count), side="left")
        stops = np.searchsorted(lab, np.arange(count), side="right")
        has = stops > starts
        middle = (starts + stops - 1) // 2
        median[has] = d[order[middle[has]]]
    limit = np.maximum(factor * median, floor)[labels]
    return np.where(ok & (d < limit), (1.0 - (np.minimum(d, limit) / limit) ** 2) ** 2, 0.0)


def _point_to_plane_step(P, Q, M, w):
    """One linearised point-to-plane rigid step (R, t): minimise sum w ((R p + t - q) . m)^2."""
    J = np.concatenate([np.cross(P, M), M], axis=1)  # (p, 6)
    r = np.einsum("pc,pc->p", P - Q, M)
    H = (J * w[:, None]).T @ J + 1e-9 * np.eye(6)
    g = (J * w[:, None]).T @ r
    delta = -np.linalg.solve(H, g)
    return _rodrigues(delta[:3][None])[0], delta[3:]


def _patch_steps(P, Y, M, W, tangential, labels, count):
    """Batched rigid steps per patch (linearised), point-to-plane plus a tangential part.

    Minimises, per patch, sum w [((x - y) . m)^2 + tau |(I - m m^T)(x - y)|^2] with
    x = p + omega x (p - c) + shift, c the patch's weighted centre.

    Returns
    -------
    omega : (count, 3), shift : (count, 3), centres : (count, 3)
    """
    weight_sum = np.bincount(labels, weights=W, minlength=count)
    plain = np.bincount(labels, minlength=count).astype(float)
    centres = np.stack([np.bincount(labels, weights=W * P[:, a], minlength=count) for a in range(3)], axis=1)
    fallback = np.stack([np.bincount(labels, weights=P[:, a], minlength=count) for a in range(3)], axis=1)
    centres = np.where(weight_sum[:, None] > 1e-9, centres / np.maximum(weight_sum, 1e-300)[:, None],
                       fallback / np.maximum(plain, 1.0)[:, None])
    p = P - centres[labels]
    # metric M_i = w (m m^T + tau (I - m m^T))
    mm = np.einsum("pi,pj->pij", M, M)
    metric = W[:, None, None] * (mm + tangential[:, None, None] * (np.eye(3) - mm))
    # x - y = (p + c - y) + [-[p]x  I] [omega; shift]
    cross = np.zeros((len(p), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2] = p[:, 2], -p[:, 1]
    cross[:, 1, 0], cross[:, 1, 2] = -p[:, 2], p[:, 0]
    cross[:, 2, 0], cross[:, 2, 1] = p[:, 1], -p[:, 0]  # -[p]x
    J = np.concatenate([cross, np.broadcast_to(np.eye(3), (len(p), 3, 3))], axis=2)  # (p, 3, 6)
    JtM = np.einsum("pki,pkl->pil", J, metric)  # (p, 6, 3)
    H = np.einsum("pil,plj->pij", JtM, J).reshape(len(p), 36)
    r = P - Y
    g = np.einsum("pil,pl->pi", JtM, r)
    Hs = np.stack([np.bincount(labels, weights=H[:, a], minlength=count) for a in range(36)], axis=1)
    gs = np.stack([np.bincount(labels, weights=g[:, a], minlength=count) for a in range(6)], axis=1)
    Hs = Hs.reshape(count, 6, 6)
    scale = np.trace(Hs, axis1=1, axis2=2) / 6.0
    Hs = Hs + (1e-3 * scale + 1e-12)[:, None, None] * np.eye(6)
    delta = -np.linalg.solve(Hs, gs[..., None])[..., 0]
    return delta[:, :3], delta[:, 3:], centres


def _closest_points(P, V, F, face_tree, k=6):
    """Closest points on a mesh among the k faces whose centres (in face_tree) are nearest.

    Returns
    -------
    points : (p, 3)   distance : (p,)   face : (p,)   bary : (p, 3)
    """
    k = min(k, len(F))
    _, faces = face_tree.query(P, k=k)
    faces = faces.reshape(len(P), k)
    tri = V[F[faces.ravel()]]
    Pq = np.repeat(P, k, axis=0)
    points, bary = _closest_on_triangles(Pq, tri[:, 0], tri[:, 1], tri[:, 2])
    dist = np.linalg.norm(points - Pq, axis=1).reshape(len(P), k)
    best = np.argmin(dist, axis=1)
    pick = np.arange(len(P)) * k + best
    return points[pick], dist[np.arange(len(P)), best], faces[np.arange(len(P)), best], bary[pick]


def _point_to_mesh(P, V, F, k=6):
    """Distance from points P to the closest of the k faces (of V, F) with the nearest centres."""
    centres = V[F].mean(axis=1)
    k = min(k, len(F))
    _, faces = cKDTree(centres).query(P, k=k)
    faces = faces.reshape(len(P), k)
    tri = V[F[faces.ravel()]]
    Pq = np.repeat(P, k, axis=0)
    points, _ = _closest_on_triangles(Pq, tri[:, 0], tri[:, 1], tri[:, 2])
    return np.linalg.norm(points - Pq, axis=1).reshape(len(P), k).min(axis=1)





@dataclass
class AlignedFrames:
    """Every frame in the root mesh's topology.

    Attributes
    ----------
    vertices : (N, n, 3) float array   aligned vertices per frame
    faces : (m, 3) int array           the root mesh's faces
    residual : (N,) float array        mean two-sided distance to each frame's surface (m)
    residual_max : (N,) float array
    distortion : (N,) float array      see :class:`PairAlignment`
    seconds : (N,) float array         time spent on each frame (all attempts; wall clock)
    parent : (N,) int array            the frame each was finally aligned from (-1 for the root)
    retried : (N,) bool array          frames whose first alignment was poor and that were
                                       aligned again from other frames
    root : int
    cpu_seconds : (N,) float array     CPU time of the aligning process per frame (target
                                       surface set-up and all attempts; all its threads), which
                                       other load on the machine does not inflate
    """

    vertices: np.ndarray
    faces: np.ndarray
    residual: np.ndarray
    residual_max: np.ndarray
    distortion: np.ndarray
    seconds: np.ndarray
    parent: np.ndarray
    retried: np.ndarray
    root: int
    cpu_seconds: np.ndarray = None


def partition_tree(parent, order, chunk):
    """Cut a rooted tree into connected pieces of about ``chunk`` frames (alignment tasks).

    Parameters
    ----------
    parent : (N,) int array   -1 for the root
    order : (N,) int array    breadth-first order
    chunk : int

    Returns
    -------
    task_of : (N,) int array          the piece of every frame
    heads : list of int               the first frame of each piece (its parent lies in
                                      another piece, or it is the root); piece 0 holds the root
    task_parent : (T,) int array      the piece holding each head's parent (-1 for piece 0)

    Notes
    -----
    Bottom-up: a frame whose not-yet-assigned subtree reaches ``chunk`` frames starts a piece.
    Pieces depend on each other only through their heads' parents, so pieces whose parent
    piece is done can be aligned at the same time.
    """
    parent = np.asarray(parent)
    order = np.asarray(order)
    N = len(parent)
    pending = np.ones(N, dtype=np.int64)
    cut = np.zeros(N, dtype=bool)
    for node in order[:0:-1]:
        if pending[node] >= chunk:
            cut[node] = True
        else:
            pending[parent[node]] += pending[node]
    cut[order[0]] = True
    heads = [int(node) for node in order if cut[node]]
    task_of = np.full(N, -1, dtype=np.int64)
    for t, head in enumerate(heads):
        task_of[head] = t
    for node in order[1:]:
        if task_of[node] < 0:
            task_of[node] = task_of[parent[node]]
    task_parent = np.array([-1] + [int(task_of[parent[h]]) for h in heads[1:]], dtype=np.int64)
    return task_of, heads, task_parent


_WORKER = {}


def _init_worker(state, ticks):
    """Process-pool initializer: build the aligner once per worker; ``ticks`` counts frames."""
    V, F, colors, tets, options, seed = state
    _WORKER["aligner"] = PairwiseAligner(V, F, colors, tets=tets, options=options, seed=seed)
    _WORKER["ticks"] = ticks


def _run_task(job):
    ticks = _WORKER.get("ticks")
    return _align_task(_WORKER["aligner"], job, tick=(lambda: ticks.put(1)) if ticks is not None else None)


def _align_task(aligner, job, tick=None):
    """Align one piece of the tree: its frames in breadth-first order, from the head's parent.

    ``job`` holds: nodes (in order), parents (of each node), meshes (V, F, colors) per node,
    hints (yaw degrees per node w.r.t. its parent), entry (the head's parent index or -1),
    entry_pose (its tet pose or None), candidates (frame indices allowed as retry sources:
    the piece's frames and the entry), similarity (rows of the dissimilarity for the nodes over
    the candidates, or None), yaw_rows (same shape, yaw of node w.r.t. each candidate),
    retries, retry_factor, history (qualities from earlier pieces), exports (nodes whose pose
    other pieces need).
    """
    nodes, parents = job["nodes"], job["parents"]
    poses = {}
    if job["entry"] >= 0:
        poses[job["entry"]] = job["entry_pose"]
    candidates = np.asarray(job["candidates"])
    column = {int(c): i for i, c in enumerate(candidates)}
    aligned = np.zeros(len(candidates), dtype=bool)
    if job["entry"] >= 0:
        aligned[column[job["entry"]]] = True
    qualities = list(job["history"])
    out = {"nodes": nodes, "V": [], "residual": [], "residual_max": [], "distortion": [], "seconds": [],
           "cpu_seconds": [], "parent": [], "retried": [], "quality": [], "poses": {}}
    for i, node in enumerate(nodes):
        node = int(node)
        cpu_started = time.process_time()
        if parents[i] < 0:  # the root: its own mesh
            poses[node] = aligner.V_tet.copy()
            result = PairAlignment(V=aligner.V.copy(), X=poses[node], residual=0.0, residual_max=0.0)
            p, retried = -1, False
        else:
            V, F, C = job["meshes"][i]
            target = TargetSurface(V, F, C)
            p = int(parents[i])
            result = aligner.align(poses[p], target, yaw=job["hints"][i])
            spent = result.seconds
            limit = job["retry_factor"] * np.median(qualities) if len(qualities) >= 10 else np.inf
            retried = False
            if job["similarity"] is not None and job["retries"] > 0 and result.quality > limit:
                retried = True
                row = job["similarity"][i]
                usable = np.flatnonzero(aligned & (candidates != p))
                for j in usable[np.argsort(row[usable], kind="stable")][:job["retries"]]:
                    source = int(candidates[j])
                    other = aligner.align(poses[source], target, yaw=float(job["yaw_rows"][i][j]))
                    spent += other.seconds
                    if other.quality < result.quality:
                        result, p = other, source
                    if result.quality <= limit:
                        break
            result.seconds = spent
            poses[node] = result.X
            qualities.append(result.quality)
        aligned[column[node]] = True
        out["V"].append(result.V.astype(np.float64))
        out["residual"].append(result.residual)
        out["residual_max"].append(result.residual_max)
        out["distortion"].append(result.distortion)
        out["seconds"].append(result.seconds)
        out["cpu_seconds"].append(time.process_time() - cpu_started)
        out["parent"].append(p)
        out["retried"].append(retried)
        if parents[i] >= 0:
            out["quality"].append(result.quality)
        if node in job["exports"]:
            out["poses"][node] = result.X
        if tick is not None:
            tick()
    return out


def align_tree(aligner, meshes, tree, *, yaw=None, dissimilarity=None, retries=3, retry_factor=2.5, chunk=48,
               workers=1, progress=None):
    """Align every frame along a rooted tree, each from its parent's aligned pose.

    Parameters
    ----------
    aligner : PairwiseAligner       built on the root frame's mesh
    meshes : sequence of Mesh-like (vertices, faces, colors) or (V, F[, colors]) tuples, one per
             frame; colours are used only when the aligner has root colours
    tree : engine.similarity_tree.SimilarityTree (or anything with root, parent, order)
    yaw : (N, N) array or None      ``yaw[i, j]`` degrees about +Y turning frame j onto frame i
                                    (from ``engine.similarity.dissimilarity_matrix``)
    dissimilarity : (N, N) array or None
        With it, a frame whose alignment scores poorly (``PairAlignment.quality`` above
        ``retry_factor`` times the median so far) is aligned again from up to ``retries`` other
        already aligned frames of its piece, the most similar first; the best result is kept.
    chunk : int                     frames per piece of the tree (see :func:`partition_tree`);
                                    the result does not depend on ``workers``
    workers : int                   processes aligning independent pieces at the same time
    progress : callable(done, total) or None

    Returns
    -------
    AlignedFrames

    Notes
    -----
    Casas et al. 2012, section 3.2: pairwise non-rigid alignment across the branches of the
    shape similarity tree gives every frame the root's mesh structure.
    """
    N = len(meshes)
    order = np.asarray(tree.order)
    tree_parent = np.asarray(tree.parent)
    if len(order) != N or len(tree_parent) != N:
        raise ValueError(f"the tree has {len(order)} frames, there are {N} meshes")
    task_of, heads, task_parent = partition_tree(tree_parent, order, max(1, int(chunk)))
    members = [[] for _ in heads]
    for node in order:
        members[task_of[node]].append(int(node))
    exports = [set() for _ in heads]
    for t, head in enumerate(heads[1:], start=1):
        exports[task_parent[t]].add(int(tree_parent[head]))
    use_colours = aligner.colors is not None

    def job_for(t, history):
        nodes = members[t]
        entry = int(tree_parent[heads[t]]) if t > 0 else -1
        candidates = nodes + ([entry] if entry >= 0 else [])
        parents = [int(tree_parent[v]) for v in nodes]
        return {
            "nodes": nodes, "parents": parents,
            "meshes": [_mesh_arrays(meshes[v], use_colours) for v in nodes],
            "hints": [None if (yaw is None or p < 0) else float(yaw[v, p]) for v, p in zip(nodes, parents)],
            "entry": entry, "entry_pose": poses.get(entry), "candidates": candidates,
            "similarity": None if dissimilarity is None else np.asarray(dissimilarity)[np.ix_(nodes, candidates)],
            "yaw_rows": None if yaw is None else np.asarray(yaw)[np.ix_(nodes, candidates)],
            "retries": int(retries) if dissimilarity is not None else 0, "retry_factor": float(retry_factor),
            "history": history, "exports": exports[t],
        }

    n = aligner.n_vertices
    vertices = np.zeros((N, n, 3))
    residual, residual_max = np.zeros(N), np.zeros(N)
    distortion, seconds, cpu_seconds = np.zeros(N), np.zeros(N), np.zeros(N)
    parent = tree_parent.copy()
    retried = np.zeros(N, dtype=bool)
    poses = {}
    qualities = [None] * len(heads)
    done = 0

    def history(t):
        found, u = [], task_parent[t]
        while u >= 0:
            found.extend(qualities[u])
            u = task_parent[u]
        return found

    def tick():
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, N)

    def collect(t, out):
        idx = np.asarray(out["nodes"])
        vertices[idx] = np.stack(out["V"])
        residual[idx], residual_max[idx] = out["residual"], out["residual_max"]
        distortion[idx], seconds[idx] = out["distortion"], out["seconds"]
        cpu_seconds[idx] = out["cpu_seconds"]
        parent[idx], retried[idx] = out["parent"], out["retried"]
        poses.update(out["poses"])
        qualities[t] = out["quality"]

    children = [[] for _ in heads]
    for t in range(1, len(heads)):
        children[task_parent[t]].append(t)
    if workers <= 1 or len(heads) == 1:
        stack = [0]
        while stack:
            t = stack.pop(0)
            collect(t, _align_task(aligner, job_for(t, history(t)), tick=tick))
            stack.extend(children[t])
    else:
        import multiprocessing
        import queue as queue_module
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

        context = multiprocessing.get_context("forkserver")
        ticks = context.Queue()
        state = (aligner.V, aligner.F, aligner.colors, (aligner.V_tet, aligner.T), aligner.options, aligner.seed)
        with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_init_worker,
                                 initargs=(state, ticks)) as pool:
            running = {pool.submit(_run_task, job_for(0, [])): 0}
            while running:
                finished, _ = wait(running, timeout=0.5, return_when=FIRST_COMPLETED)
                while True:
                    try:
                        ticks.get_nowait()
                    except queue_module.Empty:
                        break
                    tick()
                for future in finished:
                    t = running.pop(future)
                    collect(t, future.result())
                    for c in children[t]:
                        running[pool.submit(_run_task, job_for(c, history(c)))] = c
        if progress is not None:
            progress(N, N)  # ticks still in the queue
    return AlignedFrames(vertices=vertices, faces=aligner.F.copy(), residual=residual, residual_max=residual_max,
                         distortion=distortion, seconds=seconds, parent=parent, retried=retried,
                         root=int(tree.root), cpu_seconds=cpu_seconds)


def _mesh_arrays(mesh, use_colours):
    if hasattr(mesh, "vertices"):
        V, F, C = mesh.vertices, mesh.faces, getattr(mesh, "colors", None)
    else:
        V, F, C = mesh[0], mesh[1], (mesh[2] if len(mesh) > 2 else None)
    return (np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64),
            None if (C is None or not use_colours) else np.asarray(C, dtype=np.float64))


@dataclass
class CaptureAlignment:
    """Everything :func:`align_captures` computed.

    Attributes
    ----------
    similarity : engine.similarity.ShapeSimilarity
    tree : engine.similarity_tree.SimilarityTree   the tree the frames were aligned along
                                                    (a chain for ``method="sequential"``)
    aligned : AlignedFrames
    timings : dict   seconds for "similarity", "tree", "tetrahedralize", "align"
    method : str     "tree" or "sequential"
    tets : (V_tet, T)   the root's tet mesh (reusable for another run with the same root)
    """

    similarity: object
    tree: object
    aligned: AlignedFrames
    timings: dict
    method: str
    tets: tuple


def align_captures(meshes, lengths, *, method="tree", root=None, options=None, window=2, workers=1,
                   retries=3, tets=None, use_colors=True, seed=0, similarity=None, progress=None):
    """Shape similarity, tree and alignment of unstructured frames of several sequences.

    Parameters
    ----------
    meshes : list of Mesh-like (vertices, faces, colors)   all frames, sequences concatenated
    lengths : (S,) int array    frames per sequence
    method : {"tree", "sequential"}
        "tree" aligns along the shape similarity tree (paper section 3); "sequential" tracks
        frame to frame from the same root (forwards and backwards, sequences end to end), the
        baseline, with no retries.
    root : int or None          root frame (default: the tree's most central frame)
    options : AlignmentOptions
    window : int                temporal filter half-width
    workers : int               processes for the dissimilarity matrix and for aligning
                                independent pieces of the tree
    retries : int               see :func:`align_tree`
    tets : (V_tet, T) or None   a tet mesh of the root (default: tetrahedralised here)
    use_colors : bool           use vertex colours as cues when every frame has them
    seed : int
    similarity : ShapeSimilarity or None   reuse an earlier computation on the same frames
    progress : callable(stage, done, total) or None
        stages "histograms", "dissimilarity", "align"

    Returns
    -------
    CaptureAlignment
    """
    from engine.similarity import shape_dissimilarity
    from engine.similarity_tree import chain_tree, similarity_tree
    from engine.tetmesh import tetrahedralize

    if method not in ("tree", "sequential"):
        raise ValueError(f"method must be 'tree' or 'sequential', got {method!r}")
    lengths = np.asarray(lengths, dtype=np.int64)
    timings = {}
    started = time.perf_counter()
    if similarity is None:
        similarity = shape_dissimilarity(meshes, lengths, window=window, workers=workers, progress=progress)
    timings["similarity"] = time.perf_counter() - started
    started = time.perf_counter()
    tree = similarity_tree(similarity.dissimilarity, root=root)
    if method == "sequential":
        tree = chain_tree(lengths, tree.root)
    timings["tree"] = time.perf_counter() - started
    base = meshes[tree.root]
    colours = all(getattr(m, "colors", None) is not None for m in meshes) and use_colors
    started = time.perf_counter()
    if tets is None:
        tets = tetrahedralize(base.vertices, base.faces, epsilon=(options or AlignmentOptions()).tet_epsilon)
    timings["tetrahedralize"] = time.perf_counter() - started
    aligner = PairwiseAligner(base.vertices, base.faces, base.colors if colours else None, tets=tets,
                              options=options, seed=seed)
    started = time.perf_counter()
    aligned = align_tree(aligner, meshes, tree, yaw=similarity.yaw,
                         dissimilarity=similarity.dissimilarity if method == "tree" else None,
                         retries=retries if method == "tree" else 0, workers=workers,
                         progress=(lambda d, t: progress("align", d, t)) if progress else None)
    timings["align"] = time.perf_counter() - started
    return CaptureAlignment(similarity=similarity, tree=tree, aligned=aligned, timings=timings, method=method,
                            tets=tets)


__all__ = ["AlignedFrames", "AlignmentOptions", "CaptureAlignment", "PairAlignment", "PairwiseAligner",
           "TargetSurface", "align_captures", "align_tree", "partition_tree",
           "farthest_point_patches", "rotation_fit"]

"""Non-rigid pairwise alignment of the root mesh onto a frame's surface (Casas et al. 2012, 3.2).

``aligner = PairwiseAligner(V_root, F_root, colors_root)`` does the expensive set-up once: it
fills the root mesh with tetrahedra, embeds the surface, builds the coarse-to-fine patch
partitions and prefactors the soft-constrained volumetric solves. The hot path,
``aligner.align(X_source, TargetSurface(V, F, colors))``, deforms the root mesh from a pose (its
tet vertices ``X_source``) onto another frame's unstructured surface:

1. rigid start: centroids, the rotation about the vertical axis suggested by the shape
   histograms, point-to-plane ICP; where that fits poorly, also the best of a ring of placements
   along the target's long axis (:mod:`engine.align.ring`);
2. coarse to fine, with about 30 patches doubling each level: every patch is matched rigidly
   to the target (closest points with compatible normals both ways, colour cues when both
   meshes carry vertex colours, robust weights, outlier rejection), and the patch-moved
   vertices become soft constraints of an as-rigid-as-possible volumetric solve (eq. 2 with
   the root's tet Laplacian ``L = G^T D G``; rotations re-estimated per tet);
3. per-vertex closest-point rounds, then the surface is projected onto the target.

The pieces: :mod:`engine.align.matching` (correspondences), :mod:`engine.align.patches`
(partitions, articulated search), :mod:`engine.align.rigid` (rigid steps), :mod:`engine.align.options`
(options, result); :mod:`engine.align.propagation` runs the aligner along the similarity tree.
"""

from __future__ import annotations

import functools
import time

import numpy as np
import scipy.sparse as sp

from engine.align.appearance import colour_floor, colour_measures
from engine.align.colour_reach import reach_colours, smoothing_passes
from engine.align.coverage import cover_uncovered, limbs_of
from engine.align.matching import (
    correspondence_weights,
    correspondences,
    point_to_mesh_distance,
    project_onto,
    reverse_correspondences,
)
from engine.align.options import AlignmentOptions, PairAlignment, better_alignment
from engine.align.patches import border_points, farthest_point_patches, patch_adjacency, patch_samples, search_patches
from engine.align.reach import reach_uncovered
from engine.align.rigid import patch_rigid_steps, rodrigues, rotation_fit, rotation_set, stack_rotations
from engine.align.ring import RING_FROM, placement_fit, refine_placement, ring_start
from engine.align.shape_histogram import is_closed, shape_centre
from engine.deform import DeformationSolver
from engine.rotations import rot_y
from engine.surface import model_size, vertex_normals


class PairwiseAligner:
    """Deforms the root mesh (through its tet mesh) onto other frames' surfaces.

    Parameters
    ----------
    V : (n, 3) float array      root surface (holes are capped for its solid): its vertices and faces
    F : (m, 3) int array        become every aligned frame's
    colors : (n, 3) float array or None   root vertex colours (colour cues when targets have them)
    tets : (V_tet, T) or None   a tet mesh of the root's solid (default: ``tetrahedralize``
                                at ``options.tet_resolution``)
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
        from engine.tetmesh import tet_barycentric, tet_gradient, tet_laplacian, tet_volumes, tetrahedralize

        self.options = options or AlignmentOptions()
        self.seed = int(seed)
        self.V = np.ascontiguousarray(V, dtype=np.float64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        self.closed = is_closed(self.F)
        self.colors = None if colors is None else np.asarray(colors, dtype=np.float64)
        if tets is None:
            tets = tetrahedralize(self.V, self.F, resolution=self.options.tet_resolution)
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
        self.patch_graph = [patch_adjacency(self.F, labels, count)
                            for labels, count in zip(self.patch_labels, counts)]
        self.patch_samples = [patch_samples(labels, count, o.search_samples, rng)
                              for labels, count in zip(self.patch_labels, counts)]
        self._search_rotations = rotation_set(o.search_angles)
        self._limbs = {}  # level -> engine.align.coverage.limbs_of, made when first needed
        self._match_subset = _subset(n, o.match_samples, seed)
        self._fine_subset = _subset(n, o.fine_match_samples, seed)
        self._tet_volume = np.abs(tet_volumes(self.V_tet, self.T))
        scale = self._laplacian_scale = float(tet_laplacian(self.V_tet, self.T).diagonal().mean())
        weights = sorted(set(list(o.stiffness[:o.levels]) + [o.final_stiffness]))
        self._solvers = {w: DeformationSolver(self.V_tet, self.T, constraints=self.B,
                                              constraint_weight=np.sqrt(w * scale)) for w in weights}
        self._eye = np.broadcast_to(np.eye(3), (len(self.T), 3, 3))

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
        starts = self._rigid_starts(np.asarray(X_source, dtype=np.float64), target, yaw)
        gate = self.options.search_gate
        best = self._best_fit(starts, target, search=gate <= 0)
        if gate > 0 and self.options.search_levels > 0 and self._search_needed(best, gate):
            searched = self._best_fit(starts, target, search=True)
            best = searched if better_alignment(searched, best, self.retry_floor) else best
        best.seconds = time.perf_counter() - started
        best.orientations = len(starts)
        return best

    def _best_fit(self, starts, target, search):
        """The fit from every rigid start, with or without the articulated search; the best kept."""
        results = [self._fit(X, target, search=search) for X in starts]
        regions = self.colour_regions
        for result in results:
            result.colour_distance, result.colour_mean = colour_measures(result.V, self.colors, target, regions)
        return min(results, key=self._orientation_score)

    def _search_needed(self, result, gate):
        """Whether a fit without the search is fitted again with it (``options.search_gate``): its
        colours disagree more than ``gate`` times the root's floor, or there are no colours to tell."""
        floor = self.retry_floor
        return not (np.isfinite(floor) and np.isfinite(result.colour_mean)) or result.colour_mean > gate * floor

    def _fit(self, X, target, search=True):
        """Coarse-to-fine patch matching and deformation from a rigidly placed pose X (with the
        articulated search on ``options.search_levels`` levels, or with none)."""
        o = self.options
        search_levels = o.search_levels if search else 0
        R = rotation_fit(self._gradients(X), self._eye, iterations=8)
        prior, pulled = R.copy(), 0
        use_colour = self.colors is not None and target.colors is not None and o.colour_weight > 0
        for level in range(o.levels):
            labels, count = self.patch_labels[level], self.patch_counts[level]
            solver = self._solvers[o.stiffness[min(level, len(o.stiffness) - 1)]]
            for round_ in range(o.rounds[min(level, len(o.rounds) - 1)]):
                S = self.B @ X
                early = round_ < o.search_rounds
                search = level < search_levels and early
                swing = o.swing_limbs and level < max(search_levels, 1) and early
                goal, confidence = self._match_patches(S, target, labels, count, use_colour, level=level,
                                                       search=search, swing=swing,
                                                       coarse=level < o.match_sample_levels,
                                                       graph=self.patch_graph[level],
                                                       reach=use_colour and level < o.colour_reach_levels)
                X, R = self._deform(X, R, solver, goal, confidence, prior)
                if o.reach_limbs and level == 0 and round_ == 0:
                    X, R, pulled = reach_uncovered(self, X, R, target)
        solver = self._solvers[o.final_stiffness]
        for _ in range(o.final_rounds):
            S = self.B @ X
            goal, confidence = self._match_vertices(S, target, use_colour)
            X, R = self._deform(X, R, solver, goal, confidence, prior)
        S = self.B @ X
        V = project_onto(S, self.F, target)
        residual, residual_max = self._residual(V, target)
        F = self._gradients(X)
        R = rotation_fit(F, R, iterations=4)
        per_tet = np.sum((F - R) ** 2, axis=(1, 2))
        # numpy's own pairwise sum, not BLAS's dot, whose partial sums follow its thread count
        distortion = float(np.sum(self._tet_volume * per_tet) / self._tet_volume.sum())
        return PairAlignment(V=V, X=X, residual=residual, residual_max=residual_max, distortion=distortion,
                             distortion_tail=self._tail(per_tet), pulled=pulled,
                             searched=search_levels > 0)

    @functools.cached_property
    def reach_colours(self):
        """The root's colours smoothed over each vertex's neighbours, NaN on patterns (:func:`reach_colours`)."""
        return reach_colours(self.V, self.colors, smoothing_passes(self.V, self.F, model_size(self.V)))

    @functools.cached_property
    def colour_floor(self):
        """The root's colour floor (:func:`engine.align.appearance.colour_floor`; NaN without colours)."""
        return colour_floor(self.V, self.F, self.colors, self.colour_regions)

    @property
    def retry_floor(self):
        """The colour floor the tree's retries and the search gate judge by: NaN when colour cues are off."""
        return self.colour_floor if self.options.colour_weight > 0 else float("nan")

    @property
    def colour_regions(self):
        """Regions whose brightness the colour measures take out: the second level's patches."""
        return self.patch_labels[min(1, len(self.patch_labels) - 1)] if self.options.colour_regions else None

    def _orientation_score(self, result):
        """Which of the results from different orientations to keep (lower is better).

        The appearance decides when both meshes carry colours (a body turned front to back
        fits a loose garment's surface as well as the right way round, but its face lands on
        the back of the head); otherwise the fit: distortion plus residual.
        """
        if np.isfinite(result.colour_distance):
            return result.colour_distance
        return result.quality

    def _tail(self, per_tet, fraction=0.05):
        """Volume-weighted mean of ``per_tet`` over the worst ``fraction`` of the solid's volume.

        A limb that slid onto its neighbour's place tears a small region (a hip, a shoulder)
        while the rest stays rigid: the mean over all tets hides it, the tail does not.
        """
        order = np.argsort(per_tet)[::-1]
        volume = self._tet_volume[order]
        take = np.cumsum(volume) <= fraction * volume.sum()
        take[0] = True
        return float(np.sum(volume[take] * per_tet[order][take]) / volume[take].sum())  # (not BLAS: see distortion)

    def _residual(self, V, target):
        """Mean and max of the two-sided surface distance between aligned V and the target."""
        forward = target.closest(V)[1]
        backward = point_to_mesh_distance(target.V, V, self.F)
        both = np.concatenate([forward, backward])
        return float(both.mean()), float(both.max())

    def _rigid_starts(self, X, target, yaw):
        """Rigid placements of X on the target to align from: the best, and a turned-round rival.

        The turn hinted by the shape histograms and no turn are both refined by point-to-plane
        ICP. A loose garment makes a body nearly symmetric front to back, and so are its
        histograms: the hint is often off by 180 degrees and the turned-round fit scores about
        as well as the right one. When the two refined placements face more than 90 degrees
        apart and the worse scores within ``orientation_margin`` of the better, both are
        returned and the caller aligns from each (:meth:`_orientation_score` decides).
        """
        o = self.options
        S = self.B @ X
        centre = shape_centre(S, self.F, closed=self.closed)
        rng = np.random.default_rng(0)
        sample = rng.choice(len(S), size=min(len(S), 600), replace=False)
        normals = vertex_normals(S, self.F)[sample]
        candidates = [0.0]
        if yaw is not None and np.isfinite(yaw) and abs(yaw) > 2.0:
            candidates.append(float(yaw))
        fits = []
        for angle in candidates:
            R0 = rot_y(np.radians(angle))
            R, t = refine_placement(S[sample], normals, R0, target.centre - R0 @ centre, target, o)
            fits.append((placement_fit(S[sample] @ R.T + t, target), R, t))
        fits.sort(key=lambda fit: fit[0])
        starts = [X @ fits[0][1].T + fits[0][2]]
        if len(fits) > 1 and fits[1][0] <= o.orientation_margin * fits[0][0]:
            front = np.array([0.0, 0.0, 1.0])
            a, b = fits[0][1] @ front, fits[1][1] @ front
            if a[0] * b[0] + a[2] * b[2] < 0.0:  # more than 90 degrees apart about +Y
                starts.append(X @ fits[1][1].T + fits[1][2])
        if o.ring_margin > 0 and fits[0][0] > RING_FROM * model_size(self.V):  # laid down or turned far
            colours = self.colors[sample] if self.colors is not None and target.colors is not None else None
            ring = ring_start(S[sample], normals, centre, target, o, colours, fits[0][1:])
            if ring is not None:
                starts.append(X @ ring[0].T + ring[1])
        return starts

    def _match_patches(self, S, target, labels, count, use_colour, level=0, search=False, swing=False, coarse=True,
                       graph=None, reach=False):
        """Rigidly match every patch to the target; returns per-vertex goals and confidences.

        The rigid steps are driven by at most ``options.match_samples`` source vertices and as
        many target vertices (fixed random subsets) on a ``coarse`` level, and at most
        ``options.fine_match_samples`` on the others; every vertex moves with its patch. After
        the ICP steps, with ``swing`` limbs swing onto what nothing covers
        (:func:`engine.align.coverage.cover_uncovered`), and with ``search`` badly fitting patches
        try articulated hypotheses (:func:`engine.align.patches.search_patches`), on ``level``'s
        patches. With ``graph`` (the
        level's ``patch_adjacency``) and ``options.patch_coupling`` > 0, adjacent patches' steps
        are solved together (:func:`engine.align.rigid.coupled_patch_steps`). With ``reach`` (and
        ``options.colour_reach`` > 0) matches reach for the colour (:mod:`engine.align.colour_reach`).
        """
        o = self.options
        x = S.copy()
        n = vertex_normals(S, self.F)
        size = np.bincount(labels, minlength=count).astype(float)
        colours = self.colors if use_colour else None
        pick = self._match_subset if coarse else self._fine_subset
        picked_labels = labels if pick is None else labels[pick]
        picked_colours = colours if colours is None or pick is None else colours[pick]
        target_pick = _subset(len(target.V), o.match_samples if coarse else o.fine_match_samples, 0)
        # with reach: the matched points' smoothed colours, metres per unit of colour, the model size
        body = model_size(self.V)
        reach = (self.reach_colours[slice(None) if pick is None else pick], o.colour_reach * body, body) \
            if reach and o.colour_reach > 0 else None
        for _ in range(o.icp_steps):
            xs, ns = (x, n) if pick is None else (x[pick], n[pick])
            y, m, w, tangential, d = correspondences(xs, ns, target, o, picked_colours, picked_labels, count,
                                                     reach=reach)
            # target -> source pairs pull the source into parts of the target it does not cover
            points, src, ys, ms, ws = reverse_correspondences(x, n, self.F, target, o, labels, count,
                                                              subset=target_pick)
            P = np.concatenate([xs, points])
            Y = np.concatenate([y, ys])
            M = np.concatenate([m, ms])
            W = np.concatenate([w, ws])
            Tw = np.concatenate([tangential, np.zeros(len(src))])
            L = np.concatenate([picked_labels, labels[src]])
            coupling = None
            if graph is not None and o.patch_coupling > 0:
                coupling = border_points(x, graph) + (o.patch_coupling,)
            omega, shift, centres = patch_rigid_steps(P, Y, M, W, Tw, L, count, coupling=coupling)
            Rp = rodrigues(omega)
            x = np.einsum("pij,pj->pi", Rp[labels], x - centres[labels]) + centres[labels] + shift[labels]
            n = np.einsum("pij,pj->pi", Rp[labels], n)
        if swing or search:
            args = (target, labels, count, self.patch_samples[level], self.patch_graph[level])
        if swing:
            if level not in self._limbs:
                self._limbs[level] = limbs_of(self.V, self.patch_graph[level], labels, count)
            x, n = cover_uncovered(x, n, *args, self._limbs[level], o)
        if search:
            x, n = search_patches(x, n, *args, self._search_rotations, o)
        xs, ns = (x, n) if pick is None else (x[pick], n[pick])
        w = correspondence_weights(xs, ns, target, o, picked_labels, count)
        picked_size = size if pick is None else np.bincount(picked_labels, minlength=count).astype(float)
        support = np.bincount(picked_labels, weights=w, minlength=count) / np.maximum(picked_size, 1.0)
        confidence = np.clip(support[labels] * 1.25, 0.0, 1.0)
        return x, confidence

    def _match_vertices(self, S, target, use_colour):
        """Per-vertex closest compatible points and robust confidences."""
        n = vertex_normals(S, self.F)
        y, m, w, tangential, d = correspondences(S, n, target, self.options, self.colors if use_colour else None)
        return y, w

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
            X = solver.solve(stack_rotations(R), c * goal + (1.0 - c) * current)
        return X, R


@functools.lru_cache(maxsize=16)
def _subset(n, limit, seed):
    """Sorted indices of a fixed random subset of ``limit`` of ``n`` items, or None for all of them.

    Cached: every patch round of every alignment asks for the same subsets (read-only).
    """
    if limit is None or limit <= 0 or n <= limit:
        return None
    subset = np.sort(np.random.default_rng(seed).choice(n, size=int(limit), replace=False))
    subset.flags.writeable = False
    return subset


__all__ = ["AlignmentOptions", "PairAlignment", "PairwiseAligner"]

"""What goes into and comes out of a pairwise alignment: its options and its result.

:class:`AlignmentOptions` parameterises :class:`engine.align.pairwise.PairwiseAligner`;
:class:`PairAlignment` is what ``aligner.align`` returns (the aligned surface, the tet pose to
start children from, and the fit and distortion measures the tree's repair and the per-frame
confidence are built on).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RETRY_MARGIN = 0.1  # a retry's colours must agree better by this share to win on colours alone


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
    final_stiffness : float     the same for the per-vertex rounds (soft: pulled hard onto
                                their closest points, the vertices slide along a noisy surface
                                and the correspondence gets worse while the fit gets better)
    colour_sigma : float        RGB distance (0..1 per channel) at which colour cues fade
    colour_weight : float       tangential weight of colour cues (0 disables them)
    colour_reach : float        on the coarsest levels, matches whose smoothed colour disagrees
                                also look for the target point nearest in position and colour,
                                colour weighed at this share of the model size per unit of RGB
                                distance (:mod:`engine.align.colour_reach`; 0 turns it off)
    colour_reach_levels : int   the coarse levels whose matches reach for the colour
    colour_regions : bool       the colour measures take out each coarse patch's brightness
                                (light and exposure: engine.align.appearance)
    tangential_damping : float  weight keeping patches from sliding along the surface
    outlier_factor : float      pairs farther than this times the median distance are outliers
    rigid_iterations : int      ICP iterations of the rigid start
    rotation_prior : float      pull of each tet's rotation towards the source pose's
    search_levels : int         coarse levels whose patches also try articulated hypotheses
                                (rotations about the joint with the best-fitting neighbour)
                                and keep the best fitting one; 0 by default since session 49
                                (it was 1): with the coupled steps the search made the studio's
                                takes worse and cost a third of a fit (docs/evaluation.md)
    search_rounds : int         the first rounds of a level that search (and swing limbs)
    search_gate : float         with ``search_levels`` > 0: 0, every fit searches. Above 0: a fit runs first without the
                                search, and only one whose colours disagree more than this many
                                times the root's colour floor (or that has no colours to tell) runs
                                again with it; the better of the two is kept, judged as the tree's
                                retries judge (:func:`better_alignment`)
    swing_limbs : bool          in the first ``search_rounds`` rounds of the searching levels (of
                                the coarsest level when none searches), also swing limbs onto
                                the parts of the target nothing covers (:mod:`engine.align.coverage`):
                                an arm thrown into a punch, which patch matching leaves by the hip it fits
    reach_limbs : bool          after the coarsest level's first round, pull the root's
                                extremities (hands, feet, head) onto what nothing covers,
                                bending the limb as-rigid-as-possible (:mod:`engine.align.reach`;
                                on by default)
    graft_limbs : bool          in the repair, a frame the root left flagged has its limbs
                                grafted from the other frames' aligned poses and is
                                aligned again from there (:mod:`engine.align.limb_graft`; off by
                                default: on the studio's sparse takes it grafted almost nothing)
    search_angles : tuple       rotation angles tried about each axis (degrees, both signs)
    search_samples : int        vertices per patch used to score hypotheses
    search_cap : float          distance (m) at which a sample counts as unmatched
    match_samples : int         source vertices and target vertices that drive each patch's
                                rigid matching (a fixed random subset of each when a mesh has
                                more; all vertices still move with their patch, and the final
                                per-vertex rounds use all of them)
    match_sample_levels : int   the coarse levels that subsample so
    fine_match_samples : int    the same limit at the finer levels: a dense capture (40k-50k
                                vertices) is matched there on a fixed subset of this many, so
                                their cost follows the body rather than the vertex count (a
                                10k-vertex capture uses every vertex)
    orientation_margin : float  a rigid start facing more than 90 degrees away from the best
                                one whose fit score is within this factor of the best's is
                                aligned from too (front-back ambiguity, see ``_rigid_starts``)
    ring_margin : float         the best of a ring of rigid placements (the body laid along the
                                target's long axis, turned about it: :mod:`engine.align.ring`)
                                is aligned from too when its score is below this factor of the
                                upright start's (0: no ring)
    patch_coupling : float      pull between adjacent patches' rigid steps, relative to their
                                data (0: every patch steps on its own); a patch whose data
                                leave a motion free (a plain sleeve's twist) then moves with
                                its neighbours (``engine.align.rigid.coupled_patch_steps``).
                                1 by default since session 48: it lowers the error of loose
                                sleeves and of whole far frames, and the confidence (which reads
                                the colours) still flags what slips (docs/alignment.md)
    tet_resolution : float      lattice cells along the model size when the root is
                                tetrahedralised here (``engine.tetmesh.tetrahedralize``)
    """

    patches: int = 30
    levels: int = 4
    rounds: tuple = (6, 3, 2, 1)
    icp_steps: int = 3
    arap_steps: int = 2
    final_rounds: int = 1
    max_normal_angle: float = 60.0
    neighbours: int = 8
    stiffness: tuple = (0.5, 2.0, 8.0, 30.0)
    final_stiffness: float = 8.0
    colour_sigma: float = 0.12
    colour_weight: float = 0.0
    colour_reach: float = 0.18
    colour_reach_levels: int = 1
    colour_regions: bool = True
    tangential_damping: float = 0.05
    outlier_factor: float = 3.0
    rigid_iterations: int = 15
    rotation_prior: float = 0.0
    search_levels: int = 0
    search_rounds: int = 3
    search_gate: float = 0.0
    swing_limbs: bool = False
    reach_limbs: bool = True
    graft_limbs: bool = False
    search_angles: tuple = (30.0, 60.0, 90.0)
    search_samples: int = 24
    search_cap: float = 0.05
    patch_coupling: float = 1.0
    tet_resolution: float = 48.0
    orientation_margin: float = 1.25
    ring_margin: float = 0.93
    match_samples: int = 3000
    match_sample_levels: int = 2
    fine_match_samples: int = 12000


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
    distortion_tail : float     the same over the worst 5% of the solid's volume (a torn hip
                                or shoulder where a limb slid onto another's place)
    seconds : float
    colour_distance : float     median RGB distance between the root's vertex colours and the
                                target's where they landed (NaN when either has no colours)
    colour_mean : float         mean of those distances (NaN without colours): what the frame's
                                confidence reads (:mod:`engine.align.appearance`)
    orientations : int          rigid starts aligned from (2 or 3: front and back ambiguous, the ring's best)
    pulled : int                limbs pulled onto what nothing covered (``reach_limbs``) in the
                                alignment kept
    searched : bool             the fit kept ran the articulated search (``search_gate``)
    """

    V: np.ndarray
    X: np.ndarray
    residual: float
    residual_max: float
    distortion: float = 0.0
    distortion_tail: float = 0.0
    seconds: float = 0.0
    colour_distance: float = float("nan")
    colour_mean: float = float("nan")
    orientations: int = 1
    pulled: int = 0
    searched: bool = False

    @property
    def quality(self):
        """A single badness score: distortion plus mean residual in units of 5 cm."""
        return self.distortion + self.residual / 0.05


def better_alignment(other, result, floor):
    """Whether a retry's result replaces the one so far: with colours, one whose colours agree
    better by more than ``RETRY_MARGIN`` (a body turned or slid can fit and tear no worse), and
    not one that agrees worse by as much; between those (a periodic print agrees about as well
    one period off), and without colours, the lower quality score."""
    if np.isfinite(floor) and np.isfinite(other.colour_mean) and np.isfinite(result.colour_mean):
        if other.colour_mean < (1.0 - RETRY_MARGIN) * result.colour_mean:
            return True
        if result.colour_mean < (1.0 - RETRY_MARGIN) * other.colour_mean:
            return False
    return other.quality < result.quality


__all__ = ["RETRY_MARGIN", "AlignmentOptions", "PairAlignment", "better_alignment"]

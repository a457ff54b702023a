"""Aligning unstructured capture frames into one mesh structure (Casas et al. 2012, section 3).

One module per step, in pipeline order:

``shape_histogram``  ``H = shape_histogram(V, F, radius=...)``      volumetric shape histograms
``similarity``       ``D, yaw = dissimilarity_matrix(H)``, ``shape_dissimilarity(meshes, lengths)``
``similarity_tree``  ``tree = similarity_tree(D)``                   pruned minimum spanning tree
``matching``         ``TargetSurface(V, F)``, correspondences on a frame's surface
``compiled``         their inner loops in numba: closest points among candidate faces, the
                     colour cues' choice, the rotation fit, the patches' normal equations
``rigid``            ``rotation_fit``, point-to-plane and per-patch rigid steps
``patches``          ``farthest_point_patches``, the articulated patch search
``pairwise``         ``PairwiseAligner(V, F).align(X, target)``      one frame onto another
``pieces``           one piece of the tree aligned (with retries), here or in a worker process
``propagation``      ``align_tree(aligner, meshes, tree)``           every frame from its parent
``repair``           ``repair_alignment(aligner, meshes, aligned)``  per-frame confidence; slipped
                     frames aligned again from the root and trusted frames
``repair_waves``     the repair's alignments in waves through a task runner, or one by one
``captures``         ``align_captures(meshes, lengths)``             all of the above, end to end
``facing``           ``body_facing(V)``: the way a body's front faces (feet ahead of ankles)
``evaluation``       ``score_alignment``, the pattern pictures (fig. 2)
``breakdown``        ``error_breakdown``: where the error lies (parts, frames, tree depth) and
                     whether the confidence's flag finds the bad frames
"""

from engine.align.captures import CaptureAlignment, align_captures
from engine.align.evaluation import (
    correspondence_errors,
    error_summary,
    pattern_colors,
    pattern_frames,
    pattern_render,
    pattern_sheet,
    score_alignment,
    surface_coordinates,
    true_positions,
)
from engine.align.facing import body_facing, body_frame
from engine.align.matching import TargetSurface
from engine.align.pairwise import AlignmentOptions, PairAlignment, PairwiseAligner
from engine.align.patches import farthest_point_patches
from engine.align.pictures import similarity_image, tree_image
from engine.align.propagation import AlignedFrames, align_tree, partition_tree
from engine.align.repair import alignment_confidence, repair_alignment
from engine.align.rigid import rotation_fit
from engine.align.shape_histogram import (
    best_rotation,
    correlation_over_rotations,
    histogram_distance,
    histogram_norm2,
    histogram_sectors,
    is_closed,
    refine_rotation,
    rotation_correlation,
    shape_centre,
    shape_histogram,
)
from engine.align.similarity import (
    HISTOGRAM_DEFAULTS,
    ShapeSimilarity,
    dissimilarity_matrix,
    frame_histograms,
    histogram_radius,
    shape_dissimilarity,
    temporal_filter,
)
from engine.align.similarity_tree import (
    SimilarityTree,
    chain_tree,
    pruned_graph,
    pruning_threshold,
    reconnect_components,
    rooted_tree,
    similarity_tree,
    tree_root,
)

__all__ = [
    # shape histograms
    "best_rotation", "correlation_over_rotations", "histogram_distance", "histogram_norm2",
    "histogram_sectors", "is_closed", "refine_rotation", "rotation_correlation", "shape_centre",
    "shape_histogram",
    # similarity
    "HISTOGRAM_DEFAULTS", "ShapeSimilarity", "dissimilarity_matrix", "frame_histograms", "histogram_radius",
    "shape_dissimilarity", "similarity_image", "temporal_filter",
    # tree
    "SimilarityTree", "chain_tree", "pruned_graph", "pruning_threshold", "reconnect_components",
    "rooted_tree", "similarity_tree", "tree_image", "tree_root",
    # pairwise aligner
    "AlignmentOptions", "PairAlignment", "PairwiseAligner", "TargetSurface", "farthest_point_patches",
    "rotation_fit",
    # propagation
    "AlignedFrames", "CaptureAlignment", "align_captures", "align_tree", "alignment_confidence", "partition_tree",
    "repair_alignment",
    # evaluation
    "body_facing", "body_frame", "correspondence_errors", "error_summary", "pattern_colors", "pattern_frames",
    "pattern_render", "pattern_sheet", "score_alignment", "surface_coordinates", "true_positions",
]

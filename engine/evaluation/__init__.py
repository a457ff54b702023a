"""Accuracy and cost of mesh blending (Casas et al. 2012, section 4.2: Table I, figs. 3-6).

Every error is a per-vertex Euclidean distance in metres (reported in mm and in % of the space's
model size) against a reference:

- ``blend_errors``: linear, hybrid with 1 and 3 references, the space's own hybrid (to its
  epsilon) and non-linear blending against the exact non-linear blend, over a grid of weight
  vectors x all phase samples, plus the time per frame of each (Table I over a grid);
- ``heatmap_figure``: one pose coloured by that error, method by method (fig. 3);
- ``epsilon_sweep`` / ``sweep_figure``: the hybrid rebuilt for several epsilons: error, references,
  correction memory and corrected surface area (figs. 4-6);
- ``ground_truth_comparison``: beyond the paper, blends of synthetic gaits against the generator's
  own motion at the in-between parameters (``gait_truth``).

The non-linear blends at a weight vector are computed once per weight and shared through a
``BlendCache``, which also holds the hybrids built in memory. Nothing here reads or writes files;
figures are returned as RGB arrays.

Modules: ``table`` (Table I and the ``BlendCache``), ``figures`` (figs. 3, 5 and 6),
``epsilon`` (the epsilon sweep and uniform subdivision), ``ground_truth`` (the generator's truth).
"""

from engine.evaluation.epsilon import EPSILONS_MM, corrected_vertices, epsilon_sweep, uniform_subdivision, vertex_areas
from engine.evaluation.figures import heatmap_figure, pose_errors, sweep_figure
from engine.evaluation.ground_truth import gait_truth, ground_truth_comparison, true_samples
from engine.evaluation.table import LABELS, METHODS, BlendCache, blend_errors, time_per_frame, weight_grid

__all__ = [
    "METHODS", "LABELS", "EPSILONS_MM", "BlendCache", "weight_grid", "time_per_frame", "blend_errors", "pose_errors",
    "heatmap_figure", "vertex_areas", "corrected_vertices", "epsilon_sweep", "uniform_subdivision", "sweep_figure",
    "gait_truth", "true_samples", "ground_truth_comparison",
]

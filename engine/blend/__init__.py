"""Mesh blending (Casas et al. 2012, section 4): linear, exact non-linear and hybrid.

``LinearBlender``, ``PhasedNonlinearBlender`` and ``HybridBlender`` share one interface:
``blender.blend(weights, phase, out=None) -> (n, 3)`` for N non-negative weights and a phase in
[0, 1] on the sources' common phase grid. ``MotionSpace`` builds them from a motion-space file.
"""

from engine.blend.corrections import Corrections
from engine.blend.hybrid import HybridBlender
from engine.blend.hybrid_build import HybridReport, build_hybrid
from engine.blend.linear import LinearBlender
from engine.blend.nonlinear import (
    FrameDecomposer,
    NonlinearBlender,
    PhasedNonlinearBlender,
    VolumetricEmbedding,
    decompose_frames,
)
from engine.blend.phase import phase_of_sample, phase_samples
from engine.blend.simplex import SimplexTree

__all__ = [
    "Corrections", "HybridBlender", "HybridReport", "build_hybrid", "LinearBlender", "FrameDecomposer",
    "NonlinearBlender", "PhasedNonlinearBlender", "VolumetricEmbedding", "decompose_frames",
    "phase_of_sample", "phase_samples", "SimplexTree",
]

"""The synthetic studio: a real body and real motion, reconstructed per frame like a multi-view studio.

The MakeHuman body (CC0), dressed in a flared skirt and wide sleeves that lag with their own
dynamics (``body``, ``garment``), performs CMU motion capture retargeted onto its skeleton
(``bvh``, ``retarget``) or key-framed contact poses and reaches (``poses``); every frame is then
reconstructed on its own from the volume (``voxelize``, ``reconstruct``): limbs that touch merge,
holes and open boundaries change from frame to frame, fragments float, noise lies along the
normals. Files may be written in millimetres or Z up (``axes``); the ground truth stays metres, Y up.
"""

from engine.synthetic.studio.axes import (
    axes_record,
    from_metres_y_up,
    to_file,
    to_metres_y_up,
    truth_to_file,
)
from engine.synthetic.studio.body import (
    PARTS,
    StudioBody,
    StudioSkeleton,
    build_studio_body,
)
from engine.synthetic.studio.bvh import Bvh, BvhError, forward_kinematics, parse_bvh
from engine.synthetic.studio.presets import (
    STUDIO,
    STUDIO_PRESETS,
    STUDIO_TINY,
    StudioPreset,
)
from engine.synthetic.studio.reconstruct import StudioCamera, reconstruct_frame
from engine.synthetic.studio.retarget import SkeletonMotion, retarget
from engine.synthetic.studio.sequences import (
    StudioSequenceSpec,
    generate_studio_sequence,
    head_marks,
    reconstruct_frames,
    studio_sequence_data,
    summarise_frames,
)

__all__ = [
    "axes_record", "from_metres_y_up", "to_file", "to_metres_y_up", "truth_to_file", "PARTS", "StudioBody", "StudioSkeleton",
    "build_studio_body", "Bvh", "BvhError", "forward_kinematics", "parse_bvh", "STUDIO", "STUDIO_PRESETS",
    "STUDIO_TINY", "StudioPreset", "StudioCamera", "reconstruct_frame", "SkeletonMotion", "retarget",
    "StudioSequenceSpec", "generate_studio_sequence", "head_marks", "reconstruct_frames", "studio_sequence_data",
    "summarise_frames",
]

"""The source object reconstructed as 3D Gaussians from its video, masks and SpaT prior, and its poses
refined photometrically against it (:mod:`.align`), hinged parts kept on their hinges (:mod:`.joints`)."""

from .align import Alignment, AlignOptions, align_poses
from .fit import Reconstruction, ReconstructOptions, reconstruct_object
from .joints import Hinge, hinges_from_metadata

__all__ = ["reconstruct_object", "ReconstructOptions", "Reconstruction", "align_poses", "AlignOptions", "Alignment",
           "Hinge", "hinges_from_metadata"]

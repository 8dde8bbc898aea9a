"""The source object reconstructed as 3D Gaussians from its video, masks and SpaT prior (issue 15 §2),
and its poses refined photometrically against it (issue 16 §1, :mod:`.align`), hinged parts kept on their
hinges (:mod:`.joints`)."""

from .align import Alignment, AlignOptions, align_poses
from .fit import Reconstruction, ReconstructOptions, reconstruct_object
from .joints import Hinge, hinges_from_metadata

__all__ = ["reconstruct_object", "ReconstructOptions", "Reconstruction", "align_poses", "AlignOptions", "Alignment",
           "Hinge", "hinges_from_metadata"]

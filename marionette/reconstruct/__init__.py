"""The source object reconstructed as 3D Gaussians from its video, masks and SpaT prior (issue 15 §2)."""

from .fit import Reconstruction, ReconstructOptions, reconstruct_object

__all__ = ["reconstruct_object", "ReconstructOptions", "Reconstruction"]

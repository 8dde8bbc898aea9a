"""Reading and writing: 3DGS .ply, SpaT prior .npz, videos, images and masks."""

from .gltf import write_gltf_animation
from .ply import read_ply, read_ply_property, write_ply
from .prior import read_prior, write_prior
from .splat_anim import SplatAnimation, read_ply_frames, read_splat_animation, write_splat_animation
from .video import Video, read_image, read_mask, read_masks, read_video, write_image, write_video

__all__ = [
    "read_ply", "write_ply", "read_ply_property",
    "read_prior", "write_prior",
    "SplatAnimation", "read_splat_animation", "write_splat_animation", "read_ply_frames", "write_gltf_animation",
    "Video", "read_video", "read_masks", "read_mask", "read_image", "write_video", "write_image",
]

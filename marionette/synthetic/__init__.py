"""Synthetic rigid-motion videos with exact ground truth.

Procedurally textured objects made of planar faces (a box, or a body with a
hinged lid) move in front of a 60° pinhole camera, static or moving, and are
rendered by an exact ray–plane renderer with supersampled anti-aliasing. Each
scene carries per-frame masks, per-part masks, depth maps, the camera's poses
and the ground-truth object poses in the SpaT prior convention (docs/DESIGN.md):
the demo's source video, the tests' input and the motion-extraction
benchmarks' reference.
"""

from ._scene import (
    CAMERA_MOTIONS,
    MOTIONS,
    OBJECTS,
    TARGET_OBJECTS,
    SyntheticScene,
    make_scene,
    object_view,
    render_object_image,
)
from .perturb import perturbed_prior

__all__ = ["CAMERA_MOTIONS", "MOTIONS", "OBJECTS", "TARGET_OBJECTS", "SyntheticScene", "make_scene",
           "object_view", "perturbed_prior", "render_object_image"]

"""Synthetic rigid-motion videos with exact ground truth.

Procedurally textured objects made of planar faces (a box, or a body with a
hinged lid) move in front of a static 60° pinhole camera and are rendered by
an exact ray–plane renderer with supersampled anti-aliasing. Each scene
carries per-frame masks, per-part masks and the ground-truth poses in the
SpaT prior convention (DESIGN.md): the demo's source video, the tests' input
and the motion-extraction benchmarks' reference.
"""

from ._scene import (
    MOTIONS,
    OBJECTS,
    TARGET_OBJECTS,
    SyntheticScene,
    make_scene,
    render_object_image,
)

__all__ = ["MOTIONS", "OBJECTS", "TARGET_OBJECTS", "SyntheticScene", "make_scene", "render_object_image"]

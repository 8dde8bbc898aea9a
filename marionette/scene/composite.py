"""The moving object composited into the photo's scene.

Each frame is the object rendered with its alpha over the clean plate
(:func:`~marionette.scene.plate.clean_plate`), and the plate is a plane at
the object's depth facing the reference camera, so a moving camera (orbit,
dolly, a camera path) sees it with the parallax a backdrop has: the plate is
warped by the plane's homography; a camera equal to the reference one copies
it untouched.

**The photo's own detail on the object.** The lift's surfels blur the photo
a little (they overlap to close the surface), so the object rendered at its
rest pose is not quite the photo. The difference, ``photo - frame 0``, is a
detail layer in the photo's pixel grid. Every surfel carries the photo pixel
it was sampled from, and how squarely it faced the reference camera (walls
and steep slopes, seen edge-on in the photo, carry none of it): one more
render of those as colours gives, per output pixel, where on the photo the
visible surface came from, and the layer is read there. Frame 0 then
reproduces the photo, and the texture keeps the photo's sharpness as the
object turns (the back, which mirrors the front, gets the mirrored detail).

The positions a render reports are blended across overlapping splats, and
on a curved surface the nearer neighbours (toward the bulge) weigh more:
frame 0 reports pixel ``x`` as ``x + d(x)``, ``d`` up to about a pixel. The
layer is kept on the photo's grid and read at ``x`` where ``x + d(x)`` is
the position reported (a fixed point), so frame 0 reads it exactly where it
was made.

What the detail layer cannot carry (the outline: the lift's soft edge
spills a pixel over the scene, and the fringe's detail weight is small) is
kept as a last residual, ``photo - frame 0``, shown where the object's
render is still what it was at frame 0 (a pixel's weight falls off with the
change of its colour and coverage): an object, or a part of it, that has not
moved is the photo, and the residual fades where it moves away. It applies
to the photo's own camera only.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from scipy import ndimage

from ..camera import Camera
from ..gaussians import Gaussians, rgb_to_sh
from ..geometry import quaternion_to_matrix
from ..render import RenderOutput, render

__all__ = ["SceneCompositor"]

#: Surfels facing the reference camera at a cosine below ``_FACING[0]`` (walls, the steepest slopes, read from
#: a blurred photo) carry no detail, above ``_FACING[1]`` all of it.
_FACING = (0.15, 0.5)
#: Where frame 0's detail weight is below this (the rim's soft fringe), the detail layer is 0: dividing by
#: it would blow the fringe's error up; below ``_FULL_WEIGHT`` it is divided by that instead (frame 0 is then
#: not quite exact on the rim, and the rim's error is not drawn across the object when it turns).
_MIN_WEIGHT = 0.05
_FULL_WEIGHT = 0.25
#: Fixed-point steps inverting frame 0's map from pixels to the photo positions the render reports.
_INVERSE_STEPS = 4
#: Change of a pixel's object colour and coverage since frame 0 (RMS over the four, in [0, 1]) at which the
#: last residual has faded to exp(-1/2).
_KEEP_SCALE = 0.02


def _facing(gaussians: Gaussians, camera: Camera) -> np.ndarray:
    """(N,) in [0, 1]: how squarely each surfel's normal (its thinnest axis) faces ``camera``."""
    rotations = quaternion_to_matrix(gaussians.quats.astype(np.float64))  # (N, 3, 3), columns the local axes
    thinnest = np.argmin(gaussians.log_scales, axis=1)
    normals = rotations[np.arange(len(gaussians)), :, thinnest]  # (N, 3) world
    w2c = camera.world_to_camera
    rays = gaussians.means.astype(np.float64) @ w2c[:3, :3].T + w2c[:3, 3]
    cosine = np.abs(np.einsum("nc,nc->n", normals @ w2c[:3, :3].T, rays)) / np.maximum(
        np.linalg.norm(rays, axis=1), 1e-12)
    return np.clip((cosine - _FACING[0]) / (_FACING[1] - _FACING[0]), 0.0, 1.0)


def _plane_homography(reference: Camera, camera: Camera, depth: float) -> np.ndarray | None:
    """(3, 3) map from ``camera``'s pixels to ``reference``'s for the plane ``z = depth`` of the reference
    camera; None when the camera is the reference one (nothing to warp), zeros when the plane is behind it."""
    if (camera.width, camera.height) == (reference.width, reference.height) and np.allclose(
            camera.K, reference.K) and np.allclose(camera.world_to_camera, reference.world_to_camera):
        return None
    corners = np.array([[0, 0], [reference.width - 1, 0], [0, reference.height - 1],
                        [reference.width - 1, reference.height - 1]], np.float64)
    rays = np.c_[corners, np.ones(4)] @ np.linalg.inv(reference.K).T
    points_ref = rays * depth  # on the plane, reference camera frame
    ref_to_cam = camera.world_to_camera @ np.linalg.inv(reference.world_to_camera)
    points = points_ref @ ref_to_cam[:3, :3].T + ref_to_cam[:3, 3]
    if np.any(points[:, 2] <= 1e-9 * depth):
        return np.zeros((3, 3))  # the plane is behind the camera: show the plate's edge colour
    seen = points @ camera.K.T
    seen = seen[:, :2] / seen[:, 2:]
    return cv2.getPerspectiveTransform(seen.astype(np.float32), corners.astype(np.float32))


@dataclasses.dataclass(frozen=True)
class SceneCompositor:
    """Renders frames of moving Gaussians inside a photo's scene.

    Attributes
    ----------
    plate : (H, W, 3) float32 in [0, 1], the photo without its object.
    camera : Camera, the photo's (reference) camera.
    depth : float, camera z of the plate's plane in the reference camera.
    features : Gaussians, the object's surfels coloured with (w u / W, w v / H, w): each one's photo pixel
        ``(u, v)`` and detail weight ``w``.
    rest : (H, W, 4) float32, frame 0's object render (premultiplied colour and coverage).
    detail : (H, W, 3) float32, the detail layer, or None without one.
    shift : (H, W, 2) float32, ``d``: frame 0's reported photo position of each pixel minus the pixel (None
        without a detail layer).
    residual : (H, W, 3) float32, ``photo - frame 0`` with the detail layer, or None without it.
    """

    plate: np.ndarray
    camera: Camera
    depth: float
    features: Gaussians
    rest: np.ndarray
    detail: np.ndarray | None = None
    shift: np.ndarray | None = None
    residual: np.ndarray | None = None

    @staticmethod
    def from_lift(gaussians: Gaussians, camera: Camera, pixel_of: np.ndarray, photo: np.ndarray,
                  plate: np.ndarray, detail: bool = True, unmoved: bool = True) -> "SceneCompositor":
        """A compositor for a lifted photo.

        gaussians (N) at rest in the world; camera the photo's; pixel_of (N, 2) the photo pixel of each;
        photo (H, W, 3|4) uint8; plate (H, W, 3) uint8 (:func:`~marionette.scene.plate.clean_plate`);
        ``detail`` False leaves the detail layer and the last residual out (frame 0 is then the lift's own
        render); ``unmoved`` False leaves the last residual out (what has not moved is then not quite the photo).
        """
        w2c = camera.world_to_camera
        depth = float(np.median(gaussians.means.astype(np.float64) @ w2c[2, :3] + w2c[2, 3]))
        weight = _facing(gaussians, camera)
        encoded = np.stack([weight * (pixel_of[:, 0] + 0.5) / camera.width,
                            weight * (pixel_of[:, 1] + 0.5) / camera.height, weight], axis=1)
        features = dataclasses.replace(gaussians, sh=rgb_to_sh(encoded)[:, None, :])
        shown = render(gaussians, camera, (0.0, 0.0, 0.0))  # frame 0, rendered once for all the layers
        compositor = SceneCompositor(plate.astype(np.float32) / 255.0, camera, depth, features,
                                     np.concatenate([shown.image, shown.alpha[..., None]], axis=2))
        if not detail:
            return compositor
        seen = render(features, camera, (0.0, 0.0, 0.0)).image
        weight = seen[..., 2]
        valid = weight >= _MIN_WEIGHT
        difference = photo[..., :3].astype(np.float32) / 255.0 - compositor._layers(shown, None, camera)
        layer = np.where(valid[..., None], np.clip(difference / np.maximum(weight, _FULL_WEIGHT)[..., None], -1.0, 1.0),
                         0.0).astype(np.float32)
        shift = np.zeros((camera.height, camera.width, 2), np.float32)
        if valid.any():
            u, v = compositor._reported(seen)
            grid_v, grid_u = np.mgrid[:camera.height, :camera.width]
            # Beyond the valid pixels d takes its nearest valid value, so the fixed point stays smooth.
            _, (iy, ix) = ndimage.distance_transform_edt(~valid, return_indices=True)
            shift[...] = np.stack([(u - grid_u)[iy, ix], (v - grid_v)[iy, ix]], axis=2)
        compositor = dataclasses.replace(compositor, detail=layer, shift=shift)
        if not unmoved:
            return compositor
        residual = photo[..., :3].astype(np.float32) / 255.0 - compositor._layers(shown, seen, camera)
        return dataclasses.replace(compositor, residual=residual)

    def _reported(self, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A features render (h, w, 3) → the photo positions (u, v) it reports, (h, w) float32 each."""
        safe = np.maximum(seen[..., 2], 1e-6)
        return ((seen[..., 0] / safe * self.camera.width - 0.5).astype(np.float32),
                (seen[..., 1] / safe * self.camera.height - 0.5).astype(np.float32))

    def background(self, camera: Camera) -> np.ndarray:
        """(h, w, 3) float32: the plate as ``camera`` sees its plane."""
        homography = _plane_homography(self.camera, camera, self.depth)
        if homography is None:
            return self.plate
        return cv2.warpPerspective(self.plate, homography, (camera.width, camera.height),
                                   flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT_101)

    def _layers(self, shown: RenderOutput, seen: np.ndarray | None, camera: Camera) -> np.ndarray:
        """(h, w, 3) float32 frame from the object's render (over black) and its features' render ``seen``
        (h, w, 3; None: no detail): the object over the plate, the last residual where nothing changed, and
        the detail layer read where the surface came from."""
        background = self.background(camera)
        frame = shown.image + (1.0 - shown.alpha)[..., None] * background
        if self.residual is not None and background is self.plate:  # the photo's own camera
            change = np.concatenate([shown.image, shown.alpha[..., None]], axis=2) - self.rest
            keep = np.exp(-0.5 * (change**2).mean(axis=2) / _KEEP_SCALE**2)
            frame = frame + keep[..., None] * self.residual
        if seen is not None:
            weight = seen[..., 2]
            u, v = self._reported(seen)
            x, y = u, v
            for _ in range(_INVERSE_STEPS):  # the photo pixel x whose reported position x + d(x) is (u, v)
                d = cv2.remap(self.shift, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                x, y = u - d[..., 0], v - d[..., 1]
            read = cv2.remap(self.detail, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            frame = frame + np.where((weight > 1e-3)[..., None], weight[..., None] * read, 0.0)
        return np.clip(frame, 0.0, 1.0)

    def frame(self, gaussians: Gaussians, features: Gaussians, camera: Camera) -> np.ndarray:
        """(h, w, 3) uint8 frame of the moved ``gaussians`` and of ``features`` moved alike, seen by ``camera``."""
        shown = render(gaussians, camera, (0.0, 0.0, 0.0))  # premultiplied by coverage
        seen = None if self.detail is None else render(features, camera, (0.0, 0.0, 0.0)).image
        return (self._layers(shown, seen, camera) * 255.0 + 0.5).astype(np.uint8)

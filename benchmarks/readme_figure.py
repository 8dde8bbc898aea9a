"""Make the README's pictures: a real clip's motion transferred onto a real photo.

Needs ``../shared/data`` (DAVIS car-turn and the RealFusion teapot). Writes
``docs/images/readme_result.png``, source frames (top) over result frames
(bottom) at five moments, and ``docs/images/readme.webp``, the source beside
the result as a looping animation (WebP: a third of a GIF's size on a
photographed clip).

    python benchmarks/readme_figure.py [--source car-turn] [--target teapot]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from marionette import pipeline
from marionette.camera import Camera
from marionette.io import read_video, write_image
from marionette.progress import Reporter

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
IMAGES = Path(__file__).resolve().parents[1] / "docs" / "images"


def contact_sheet(rows: list[list[np.ndarray]], height: int = 180, pad: int = 4) -> np.ndarray:
    """Rows of (H, W, 3) uint8 images → one sheet, each image scaled to ``height``."""
    lines = []
    for row in rows:
        tiles = [cv2.resize(im, (int(im.shape[1] * height / im.shape[0]), height), interpolation=cv2.INTER_AREA)
                 for im in row]
        tiles = [np.pad(t, ((pad, pad), (pad, pad), (0, 0)), constant_values=255) for t in tiles]
        lines.append(np.concatenate(tiles, axis=1))
    width = max(line.shape[1] for line in lines)
    lines = [np.pad(line, ((0, 0), (0, width - line.shape[1]), (0, 0)), constant_values=255) for line in lines]
    return np.concatenate(lines, axis=0)


def write_webp(path: Path, frames: list[np.ndarray], fps: float, quality: int = 65) -> None:
    """(H, W, 3) uint8 frames → an animated WebP that loops forever."""
    images = [Image.fromarray(frame) for frame in frames]
    images[0].save(path, format="WEBP", save_all=True, append_images=images[1:], duration=round(1000 / fps),
                   loop=0, quality=quality, method=6)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default="davis_car-turn")
    parser.add_argument("--target", default="realfusion15_colorful_teapot/image_rgba.png")
    parser.add_argument("--output", type=Path, default=IMAGES / "readme_result.png")
    parser.add_argument("--animation", type=Path, default=IMAGES / "readme.webp")
    parser.add_argument("--height", type=int, default=180, help="the animation's height in pixels")
    parser.add_argument("--stride", type=int, default=2, help="the animation shows every N-th frame")
    args = parser.parse_args()
    src = DATA / "videos" / args.source
    reporter = Reporter()
    prior = pipeline.extract(src / "frames", masks=src / "masks", reporter=reporter)
    target = pipeline.load_target(DATA / "images" / args.target, prior=prior)
    trajectory = pipeline.transfer(prior, target)
    # Show the result on a canvas of the source's aspect ratio, framed to keep it in view.
    source = read_video(src / "frames").frames
    cam = target.camera
    width = int(round(cam.height * source.shape[2] / source.shape[1]))
    k = cam.K.copy()
    k[0, 2] += (width - cam.width) / 2
    camera = pipeline.fit_view(Camera(k, cam.world_to_camera, width, cam.height), trajectory)
    frames = list(pipeline.render_frames(target.gaussians, trajectory, camera))
    picks = np.linspace(0, len(frames) - 1, 5).round().astype(int)
    sheet = contact_sheet([[source[i] for i in picks], [frames[i] for i in picks]])
    write_image(args.output, sheet)
    print(f"wrote {args.output}")
    moving = pipeline.side_by_side(source[::args.stride], frames[::args.stride], height=args.height)
    write_webp(args.animation, list(moving), prior.fps / args.stride)
    print(f"wrote {args.animation} ({args.animation.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()

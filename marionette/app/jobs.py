"""The app's work: one folder per session, uploads checked as they arrive, runs in a worker thread.

Each browser session gets a folder of its own under the app's work folder
(a random name), so two users never touch each other's files; its runs are
queued to one worker thread (two runs at once would only share the same
cores), off the request threads, and report their stage and progress.
"""

from __future__ import annotations

import queue
import secrets
import shutil
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import pipeline
from ..errors import InputError
from ..io import read_image, write_image
from ..io.video import IMAGE_SUFFIXES, open_video
from ..prior import SpatPrior
from ..progress import ProgressCallback, Reporter
from ..segment import Prompt, prompted_mask
from ..source.extract import ExtractOptions
from ..target.lift import LiftOptions, object_mask

__all__ = ["Settings", "Session", "Sessions", "VIDEO_SUFFIXES"]

#: Uploads taken as the source clip.
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".gif", ".m4v")
#: Longest side the app works at (the command line's default).
_MAX_SIDE = pipeline.DEFAULT_MAX_SIDE


@dataclass(frozen=True)
class Settings:
    """What the page sets for a run: playback, camera, motion (filmed or world), background, the prompts
    (pixels of the first source frame and of the photo, as uploaded), and the extraction's part count
    (``--parts``: a number or ``"auto"``) and focal length (``--focal``: None for the default field of
    view, ``"auto"``, or pixels of the uploaded clip)."""

    speed: float = 1.0
    frames: int | None = None
    camera: str = "static"
    motion: str = "filmed"
    background: tuple[float, float, float] | str = (1.0, 1.0, 1.0)
    source_prompt: Prompt | None = None
    target_prompt: Prompt | None = None
    parts: int | str = 1
    focal: float | str | None = None


def source_summary(prior: SpatPrior) -> str:
    """One line on the extracted motion for the page: parts, focal length, and frames whose pose was lost."""
    parts = f"{prior.num_parts} part{'s' if prior.num_parts > 1 else ''}"
    line = f"source motion: {parts} over {prior.num_frames} frames, focal length {prior.intrinsics[0, 0]:.0f} px"
    failed = len(prior.metadata.get("failed_frames") or {})
    if failed:
        line += f"; pose estimation failed at {failed} part-frames, their poses interpolated"
    return line


class _JobReporter(Reporter):
    """A quiet reporter that keeps the current stage and its share done for the page."""

    def __init__(self, status: dict) -> None:
        super().__init__(quiet=True)
        self._status = status

    @contextmanager
    def stage(self, description: str, total: int | None = None) -> Iterator[ProgressCallback]:
        self._status.update(stage=description, progress=0.0)

        def update(done: int, total_: int) -> None:
            self._status["progress"] = float(done) / max(int(total_), 1)

        with super().stage(description, total):
            yield update


@dataclass
class Session:
    """One browser session's folder, uploads and run status."""

    folder: Path
    source: Path | None = None
    target: Path | None = None
    status: dict = field(default_factory=lambda: {"state": "idle"})  # also "source": source_summary's line
    lock: threading.Lock = field(default_factory=threading.Lock)

    def upload(self, kind: str, name: str, data: bytes) -> dict:
        """Keep an uploaded source clip or photo, checked; its first frame or the photo as ``kind.png``.

        Returns ``{"width", "height", "frames"?}``. Raises :class:`InputError` for what cannot be used (the
        file is removed again), naming the file as the user did, never by its path on the server.
        """
        if kind not in ("source", "target"):
            raise InputError(f"unknown upload kind {kind!r}")
        suffix = Path(name).suffix.lower()
        allowed = VIDEO_SUFFIXES + IMAGE_SUFFIXES if kind == "source" else IMAGE_SUFFIXES
        if suffix not in allowed:
            what = "a video or an image" if kind == "source" else "an image"
            raise InputError(f"{name!r} is not {what} ({', '.join(allowed)})")
        if kind == "source" and suffix in IMAGE_SUFFIXES:
            raise InputError(f"{name!r} is a still photo; the source must be a video clip (a photo has no motion)")
        if not data:
            raise InputError(f"{name!r} is empty")
        path = self.folder / f"{kind}{suffix}"
        for old in self.folder.glob(f"{kind}.*"):
            old.unlink()
        setattr(self, kind, None)
        path.write_bytes(data)
        try:
            if kind == "source":
                video = open_video(path, max_side=_MAX_SIDE)  # at least 2 frames, or an InputError
                first, info = video.frames[0], {"frames": len(video.frames)}
                video.frames.close()
            else:
                first, info = read_image(path)[..., :3], {}
        except (InputError, OSError, ValueError) as e:
            path.unlink(missing_ok=True)
            reason = str(e).splitlines()[0].replace(str(path), name)  # the readers name the path they read
            raise InputError(reason if name in reason else f"{name!r} cannot be read: {reason}") from None
        write_image(self.folder / f"{kind}.png", first)
        setattr(self, kind, path)
        return {"width": int(first.shape[1]), "height": int(first.shape[0]), **info}

    def mask_preview(self, kind: str, prompt: Prompt | None) -> Path:
        """The mask ``prompt`` gives (None: the automatic one) drawn over the first frame or the photo."""
        image = read_image(self.folder / f"{kind}.png")[..., :3]
        if prompt is not None:
            mask = prompted_mask(image, prompt)
        elif kind == "target":
            mask = object_mask(image)
        else:
            raise InputError("click the object on the first frame (the video's automatic mask needs the whole clip)")
        shown = image.copy()
        shown[~mask] = (0.35 * shown[~mask]).astype(np.uint8)
        shown[mask] = (0.6 * shown[mask] + [0, 100, 0]).astype(np.uint8)
        out = self.folder / f"{kind}_mask.png"
        write_image(out, shown)
        return out

    def run(self, settings: Settings) -> None:
        """Extract, lift, transfer and render into ``result.mp4`` (called on the worker thread)."""
        status = self.status
        start = time.perf_counter()
        try:
            if self.source is None or self.target is None:
                raise InputError("upload a source clip and a photo first")
            reporter = _JobReporter(status)
            prior = pipeline.extract(self.source, focal=settings.focal, options=ExtractOptions(parts=settings.parts),
                                     prompt=settings.source_prompt, reporter=reporter)
            status["source"] = source_summary(prior)
            with reporter.stage("lifting target", 1):
                lifted = pipeline.load_target(self.target, options=LiftOptions(), prior=prior,
                                              prompt=settings.target_prompt)
            with reporter.stage("transfer", 1):
                trajectory = pipeline.transfer(prior, lifted, frames=settings.frames, speed=settings.speed,
                                               motion=settings.motion)
            scene = settings.background == "scene"
            cameras = pipeline.output_cameras(lifted, trajectory, settings.camera, framed=not scene)
            background = settings.background
            if scene:
                with reporter.stage("clean plate", 1):
                    background = pipeline.scene_compositor(lifted)
            result = self.folder / "result.mp4"
            pipeline.render_video(result, lifted, trajectory, cameras, fps=prior.fps, background=background,
                                  reporter=reporter)
            status.update(state="done", stage="done", progress=1.0, frames=trajectory.num_frames,
                          seconds=round(time.perf_counter() - start, 2), video="result.mp4")
        except InputError as e:
            status.update(state="error", message=str(e).splitlines()[0])
        except Exception as e:  # noqa: BLE001 - the page shows it; the server keeps serving others
            status.update(state="error", message=f"{type(e).__name__}: {e}".splitlines()[0])


class Sessions:
    """Every session of one app, under ``root``, and the worker thread that runs them."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self._sessions: dict[str, Session] = {}
        self._lock = threading.Lock()
        self._queue: queue.Queue[tuple[Session, Settings] | None] = queue.Queue()
        self._worker = threading.Thread(target=self._work, name="marionette-app-worker", daemon=True)
        self._worker.start()

    def new(self) -> str:
        """A new session's id (its folder's name)."""
        key = secrets.token_hex(8)
        folder = self.root / key
        folder.mkdir()
        with self._lock:
            self._sessions[key] = Session(folder)
        return key

    def get(self, key: str) -> Session:
        with self._lock:
            session = self._sessions.get(key)
        if session is None:
            raise InputError("unknown session; reload the page")
        return session

    def submit(self, key: str, settings: Settings) -> None:
        """Queue a run of session ``key`` (one at a time per session)."""
        session = self.get(key)
        with session.lock:
            if session.status.get("state") in ("queued", "running"):
                raise InputError("this session is already running; wait for it to finish")
            if session.source is None or session.target is None:
                raise InputError("upload a source clip and a photo first")
            (session.folder / "result.mp4").unlink(missing_ok=True)
            session.status.clear()
            session.status.update(state="queued", stage="waiting for the worker", progress=0.0)
        self._queue.put((session, settings))

    def _work(self) -> None:
        while (item := self._queue.get()) is not None:
            session, settings = item
            session.status.update(state="running")
            session.run(settings)

    def close(self, remove: bool = False) -> None:
        """Stop the worker (after the run in progress); ``remove`` deletes every session's folder."""
        self._queue.put(None)
        if remove:
            shutil.rmtree(self.root, ignore_errors=True)

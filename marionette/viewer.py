"""Interactive web viewer for animated Gaussians, served with viser.

The page plays a result with a time slider, a play/pause button and an fps
field; viser provides the free camera. The scene is shown in our world frame
(OpenCV: x right, y down, z forward), so the first view looks along +z with
−y up, as the reference camera saw the target.

:func:`serve` starts a server and returns at once (tests, notebooks);
:func:`run` is the blocking loop of ``marionette view``.
"""

from __future__ import annotations

import contextlib
import io
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import viser

from .address import check_address, port_in_use
from .errors import InputError
from .gaussians import Gaussians
from .geometry import quaternion_to_matrix
from .io.ply import read_ply
from .io.splat_anim import SplatAnimation, read_ply_frames, read_splat_animation

__all__ = ["Viewer", "serve", "run", "load_source", "covariances", "DEFAULT_FPS"]

#: Playback rate of a .ply folder, which stores none.
DEFAULT_FPS = 24.0

Source = str | Path | SplatAnimation | Sequence[Gaussians]
#: Frame t → centres (N, 3), covariances (N, 3, 3), colours (N, 3), opacities (N, 1).
FrameFn = Callable[[int], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def covariances(gaussians: Gaussians) -> np.ndarray:
    """World covariances ``R S² Rᵀ`` (N, 3, 3) float32 of the Gaussians."""
    m = quaternion_to_matrix(gaussians.quats) * np.exp(gaussians.log_scales.astype(np.float64))[:, None, :]
    return (m @ m.transpose(0, 2, 1)).astype(np.float32)


def load_source(path: str | Path) -> SplatAnimation | list[Gaussians]:
    """An animated-splat ``.npz``, a folder of per-frame ``.ply`` files or one ``.ply`` (a still)."""
    path = Path(path)
    if path.is_dir():
        return read_ply_frames(path)
    if path.suffix.lower() == ".ply":
        return [read_ply(path)]
    return read_splat_animation(path)


def _turn(cov: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``r @ cov[i] @ r.T`` for symmetric cov (M, 3, 3) and one rotation r (3, 3), as two BLAS products."""
    m = len(cov)
    x = (cov.reshape(3 * m, 3) @ r.T).reshape(m, 3, 3)  # cov[i] r^T
    return (x.transpose(0, 2, 1).reshape(3 * m, 3) @ r.T).reshape(m, 3, 3)  # (cov[i] r^T)^T r^T


def _animation_frames(anim: SplatAnimation) -> FrameFn:
    # Rest covariances once, grouped by part; frame t turns each group by its
    # part's rotation, Σ_t = R Σ_0 Rᵀ, which equals covariances(anim.frame(t)).
    traj = anim.trajectory
    members = [np.nonzero(traj.labels == k)[0] for k in range(traj.part_rotations.shape[1])]
    rest = covariances(anim.gaussians)  # (N, 3, 3)
    rest_parts = [rest[idx] for idx in members]
    rgb = np.clip(anim.gaussians.rgb, 0, 1)
    opacity = anim.gaussians.opacities[:, None]

    def frame(t: int):
        cov = np.empty_like(rest)
        for k, idx in enumerate(members):
            cov[idx] = _turn(rest_parts[k], traj.part_rotations[t, k])
        return traj.means[t], cov, rgb, opacity
    return frame


def _sequence_frames(frames: Sequence[Gaussians]) -> FrameFn:
    def frame(t: int):
        g = frames[t]
        return g.means, covariances(g), np.clip(g.rgb, 0, 1), g.opacities[:, None]
    return frame


class Viewer:
    """A running viewer; :func:`serve` makes one.

    Attributes
    ----------
    server : viser.ViserServer
    num_frames : int
    url : str
        Address of the page.
    """

    def __init__(self, server: viser.ViserServer, frame: FrameFn, num_frames: int, fps: float,
                 autoplay: bool) -> None:
        self.server, self.num_frames = server, num_frames
        self.url = f"http://{server.get_host()}:{server.get_port()}"
        self._frame, self._shown, self._lock = frame, 0, threading.Lock()
        self._stopped = threading.Event()
        server.scene.set_up_direction("-y")
        first = frame(0)
        _place_camera(server, first[0])
        self._splats = server.scene.add_gaussian_splats("/splats", *first)

        gui = server.gui
        self._slider = gui.add_slider("Frame", min=0, max=max(num_frames - 1, 0), step=1, initial_value=0,
                                      disabled=num_frames < 2)
        self._play = gui.add_button("Pause" if autoplay else "Play", disabled=num_frames < 2)
        self._fps = gui.add_number("FPS", initial_value=float(fps), min=0.1, max=240.0, step=0.1)
        self._playing = autoplay and num_frames > 1
        self._slider.on_update(lambda _: self.show(int(self._slider.value)))
        self._play.on_click(lambda _: setattr(self, "playing", not self.playing))
        self._player = threading.Thread(target=self._loop, daemon=True, name="marionette-viewer-player")
        self._player.start()

    @property
    def current(self) -> int:
        """Index of the frame on display."""
        return self._shown

    def show(self, t: int) -> None:
        """Display frame ``t`` (also moves the slider)."""
        if not 0 <= t < self.num_frames:
            raise InputError(f"frame {t} is outside 0..{self.num_frames - 1}")
        with self._lock:
            if t != self._shown:
                self._splats.set_gaussians(*self._frame(t))
                self._shown = t
        self._slider.value = t  # a no-op when the slider itself called us

    @property
    def playing(self) -> bool:
        """Whether frames advance on their own; the Play/Pause button flips it."""
        return self._playing

    @playing.setter
    def playing(self, value: bool) -> None:
        self._playing = bool(value)
        self._play.label = "Pause" if self._playing else "Play"

    def _loop(self) -> None:
        deadline = time.monotonic()
        while not self._stopped.wait(max(0.0, deadline - time.monotonic())):
            # After a slow frame, carry on from now rather than rushing to catch up.
            deadline = max(deadline + 1.0 / max(float(self._fps.value), 0.1), time.monotonic())
            if self._playing:
                self.show((self._shown + 1) % self.num_frames)

    def stop(self) -> None:
        """Stop playback and the server."""
        self._stopped.set()
        self._player.join()
        self.server.stop()


def _place_camera(server: viser.ViserServer, means: np.ndarray) -> None:
    """Look along +z (−y up) at the bulk of the Gaussians (N, 3).

    The camera stands back so that a ball holding 95 % of them would just
    fill the view's height from its near side.
    """
    centre = np.median(means, axis=0)
    radius = max(float(np.percentile(np.linalg.norm(means - centre, axis=1), 95)), 1e-6)
    cam = server.initial_camera
    distance = radius + radius / np.tan(cam.fov / 2)
    cam.position = centre - np.array([0.0, 0.0, distance])
    cam.look_at = centre
    cam.up = (0.0, -1.0, 0.0)
    cam.near, cam.far = 0.01 * distance, 100.0 * (distance + radius)


def serve(source: Source, host: str = "127.0.0.1", port: int = 8080, *, fps: float | None = None,
          autoplay: bool = True, verbose: bool = False) -> Viewer:
    """Start a viewer for ``source`` and return it at once; call ``.stop()`` when done.

    Parameters
    ----------
    source : path to an animated-splat ``.npz``, a folder of per-frame
        ``.ply`` files or one ``.ply``, a :class:`SplatAnimation`, or a sequence of Gaussians
        (one per frame, all of the same size).
    host, port : where to listen; only this machine can connect by default.
        Port 0 picks a free port; a port in use is an error (not replaced by another).
    fps : playback rate; default the animation's own (``DEFAULT_FPS`` for .ply frames).
    autoplay : start playing at once.
    verbose : let viser print its banner (on stderr) and connection messages.
    """
    port = int(port)
    check_address(host, port)
    if isinstance(source, (str, Path)):
        source = load_source(source)
    if isinstance(source, SplatAnimation):
        frame, num_frames = _animation_frames(source), source.num_frames
        fps = source.fps if fps is None else fps
    else:
        if len(source) == 0 or any(len(g) != len(source[0]) for g in source):
            raise InputError("viewer frames must be a non-empty sequence of equally many Gaussians")
        frame, num_frames = _sequence_frames(source), len(source)
        fps = DEFAULT_FPS if fps is None else fps
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a positive number, got {fps}")
    with contextlib.redirect_stdout(sys.stderr if verbose else io.StringIO()):  # stdout may hold a JSON summary
        server = viser.ViserServer(host=host, port=port, verbose=verbose)
    if port not in (0, server.get_port()):  # taken since the check: viser moved to the next free one
        server.stop()
        raise port_in_use(port)
    return Viewer(server, frame, num_frames, fps, autoplay)


def run(source: Source, host: str = "127.0.0.1", port: int = 8080, *, fps: float | None = None,
        announce: Callable[[Viewer], None] | None = None, verbose: bool = False) -> None:
    """Serve ``source`` until interrupted, then stop the server and let the KeyboardInterrupt through.

    ``announce`` is called with the running viewer (default: print its address).
    """
    viewer = serve(source, host, port, fps=fps, verbose=verbose)
    try:
        (announce or (lambda v: print(f"viewer at {v.url} (Ctrl-C to stop)")))(viewer)
        threading.Event().wait()
    finally:
        viewer.stop()

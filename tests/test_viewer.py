"""Animated-splat export and the web viewer, end to end in headless Chromium."""

import json
import subprocess
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest
from browser import CHROMIUM, browser

from marionette.errors import InputError
from marionette.gaussians import Gaussians, rgb_to_sh
from marionette.geometry import axis_angle_to_matrix
from marionette.io.ply import write_ply
from marionette.io.splat_anim import SplatAnimation, read_ply_frames, read_splat_animation, write_splat_animation
from marionette.trajectory import Trajectory
from marionette.viewer import _animation_frames, covariances, serve

MAGENTA = (1.0, 0.0, 1.0)


def _animation(n=2000, t_count=6, shift=0.0, seed=0) -> SplatAnimation:
    """Two parts of a magenta ball 3 units ahead of the camera: part 0 slides
    along +x by ``shift`` in total, part 1 also turns about z."""
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(n, 3)) * 0.25 + [0.0, 0.0, 3.0]
    quats = rng.normal(size=(n, 4))
    g = Gaussians(means, quats, np.log(rng.uniform(0.01, 0.04, (n, 3))), np.full(n, 4.0),
                  np.concatenate([rgb_to_sh(np.tile(MAGENTA, (n, 1)))[:, None], rng.normal(size=(n, 3, 3)) * 0.01],
                                 axis=1))
    labels = (means[:, 0] > 0).astype(np.int32)
    rots = np.tile(np.eye(3), (t_count, 2, 1, 1))
    rots[:, 1] = axis_angle_to_matrix(np.linspace(0, 0.5, t_count)[:, None] * [0, 0, 1])
    frame_means = np.empty((t_count, n, 3))
    for t in range(t_count):
        moved = np.einsum("nij,nj->ni", rots[t][labels], means - [0, 0, 3]) + [0, 0, 3]
        frame_means[t] = moved + [shift * t / (t_count - 1), 0, 0]
    return SplatAnimation(g, Trajectory(frame_means, rots, labels), 12.5)


def test_round_trip_is_exact(tmp_path):
    anim = _animation()
    write_splat_animation(tmp_path / "a.npz", anim.gaussians, anim.trajectory, anim.fps)
    back = read_splat_animation(tmp_path / "a.npz")
    assert back.fps == anim.fps and back.num_frames == 6
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert np.array_equal(getattr(back.gaussians, name), getattr(anim.gaussians, name)), name
    for name in ("means", "part_rotations", "labels"):
        a, b = getattr(back.trajectory, name), getattr(anim.trajectory, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert list(tmp_path.iterdir()) == [tmp_path / "a.npz"]  # no temporary left behind


def _corrupt(tmp_path, **changes) -> Path:
    anim = _animation(n=50, t_count=3)
    good = tmp_path / "good.npz"
    write_splat_animation(good, anim.gaussians, anim.trajectory, anim.fps)
    with np.load(good) as data:
        arrays = dict(data)
    for key, value in changes.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = value(arrays[key]) if callable(value) else value
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays, allow_pickle=True)
    return bad


def _with_nan(a):
    a = a.copy()
    a.flat[7] = np.nan
    return a


@pytest.mark.parametrize("key, change", [
    ("format", np.array("marionette.spat_prior")),
    ("version", np.array(2)),
    ("fps", np.array(0.0)),
    ("labels", None),
    ("frame_means", _with_nan),
    ("sh", _with_nan),
    ("part_rotations", lambda a: np.where(np.isfinite(a), np.inf, a)),
    ("frame_means", lambda a: a[:, :-1]),  # one Gaussian short
    ("part_rotations", lambda a: a[:-1]),  # one frame short
    ("quats", lambda a: a[:, :3]),
    ("sh", lambda a: np.concatenate([a, a[:, :1]], axis=1)),  # 5 coefficients
    ("labels", lambda a: a + 5),  # no such part
    ("labels", lambda a: a.astype(np.float32)),
    ("means", lambda a: np.array([object()] * len(a), dtype=object)),  # pickle
])
def test_bad_files_are_rejected_naming_the_key(tmp_path, key, change):
    bad = _corrupt(tmp_path, **{key: change})
    with pytest.raises(InputError) as err:
        read_splat_animation(bad)
    message = str(err.value)
    assert "\n" not in message
    assert f"'{key}'" in message or "pickled" in message


def test_unreadable_files_are_rejected(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 not really a zip")
    for path in (tmp_path / "missing.npz", tmp_path / "junk.npz"):
        with pytest.raises(InputError):
            read_splat_animation(path)


def test_write_rejects_mismatched_or_bad_input(tmp_path):
    anim = _animation(n=50, t_count=3)
    with pytest.raises(InputError, match="50 Gaussians"):
        write_splat_animation(tmp_path / "a.npz", anim.gaussians.subset(np.arange(49)), anim.trajectory, 10)
    with pytest.raises(InputError, match="fps"):
        write_splat_animation(tmp_path / "a.npz", anim.gaussians, anim.trajectory, float("nan"))
    assert not any(tmp_path.iterdir())


def test_viewer_covariances_match_moved_gaussians():
    # Fast path (rest covariances turned by part rotations) against the
    # obviously correct one (covariances of Trajectory.frame); float32 storage
    # of quaternions and covariances bounds the agreement at ~1e-6 relative.
    anim = _animation(n=300)
    frame = _animation_frames(anim)
    for t in (0, 3, 5):
        centres, cov, rgb, opacity = frame(t)
        _cov = covariances(anim.frame(t))
        np.testing.assert_allclose(cov, _cov, rtol=1e-4, atol=1e-8)
        assert np.array_equal(centres, anim.trajectory.means[t])
    assert np.allclose(rgb, MAGENTA, atol=1e-6) and opacity.shape == (300, 1)
    # Covariances are what the scales say: eigenvalues are the squared scales.
    eig = np.sort(np.linalg.eigvalsh(covariances(anim.gaussians)), axis=1)
    np.testing.assert_allclose(eig, np.sort(anim.gaussians.scales ** 2, axis=1), rtol=1e-4)


def test_ply_frames_folder(tmp_path):
    anim = _animation(n=100, t_count=3)
    for t in range(3):
        write_ply(tmp_path / f"{t:05d}.ply", anim.frame(t))
    frames = read_ply_frames(tmp_path)
    assert [np.array_equal(f.means, anim.trajectory.means[t]) for t, f in enumerate(frames)] == [True] * 3
    viewer = serve(tmp_path, port=0, autoplay=False)
    try:
        viewer.show(2)
        assert viewer.num_frames == 3 and np.array_equal(viewer._splats.centers, anim.trajectory.means[2])
    finally:
        viewer.stop()
    write_ply(tmp_path / "00003.ply", anim.gaussians.subset(np.arange(10)))
    with pytest.raises(InputError, match="00003.ply holds 10"):
        read_ply_frames(tmp_path)
    with pytest.raises(InputError, match="not a folder"):
        read_ply_frames(tmp_path / "00000.ply")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no .ply"):
        read_ply_frames(tmp_path / "empty")


def test_serve_localhost_show_play_and_stop(tmp_path):
    anim = _animation(n=200, t_count=6)
    write_splat_animation(tmp_path / "a.npz", anim.gaussians, anim.trajectory, anim.fps)
    viewer = serve(tmp_path / "a.npz", port=0, autoplay=False)
    try:
        assert viewer.url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(viewer.url, timeout=10) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
        viewer.show(4)
        assert viewer.current == 4
        assert np.array_equal(viewer._splats.centers, anim.trajectory.means[4])
        time.sleep(0.3)
        assert viewer.current == 4  # paused
        assert not viewer.playing
        viewer.playing = True  # what the Play button does
        seen = set()
        for _ in range(50):  # 0.5 s at 12.5 fps: about 6 frames
            seen.add(viewer.current)
            time.sleep(0.01)
        assert len(seen) >= 4
        with pytest.raises(InputError):
            viewer.show(6)
    finally:
        viewer.stop()
    with pytest.raises(OSError):
        urllib.request.urlopen(viewer.url, timeout=2)


def test_view_command_prints_json_once_serving_and_ctrl_c_exits_130(tmp_path):
    import os
    import signal
    import sys

    anim = _animation(n=200, t_count=3)
    write_splat_animation(tmp_path / "a.npz", anim.gaussians, anim.trajectory, anim.fps)
    # Its own session with SIGINT at its default, as in a terminal (see test_interrupt.py).
    proc = subprocess.Popen([sys.executable, "-m", "marionette", "view", str(tmp_path / "a.npz"), "--port", "0",
                             "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        while lines[-1:] != ["}\n"]:  # the summary, once the page is served: stdout holds nothing else
            lines.append(proc.stdout.readline())
            assert lines[-1], proc.stderr.read()
        summary = json.loads("".join(lines))
        assert summary["command"] == "view" and summary["figures"]["frames"] == 3
        with urllib.request.urlopen(summary["figures"]["url"], timeout=10) as page:
            assert page.status == 200
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["error: interrupted"]


def test_view_command_takes_the_common_options(tmp_path, capsys):
    from marionette.cli import main

    assert main(["view", str(tmp_path / "a.npz"), "--quiet", "--verbose"]) == 2
    assert capsys.readouterr().err.strip() == "error: --quiet and --verbose exclude each other"


def test_serve_rejects_bad_options():
    anim = _animation(n=20, t_count=2)
    with pytest.raises(InputError, match="port"):
        serve(anim, port=70000)
    with pytest.raises(InputError, match="host"):
        serve(anim, host="192.0.2.1", port=0)  # TEST-NET address: not this machine
    with pytest.raises(InputError, match="fps"):
        serve(anim, port=0, fps=-1)


@pytest.mark.parametrize("port", ["-1", "99999"])
def test_view_command_rejects_a_bad_port_before_loading(tmp_path, capsys, port):
    from marionette.cli import main

    assert main(["view", str(tmp_path / "missing.npz"), "--port", port]) == 2
    assert capsys.readouterr().err.strip() == f"error: port must be in 0..65535 (0: any free port), got {port}"


def test_a_port_in_use_is_an_error_not_another_port(tmp_path, capsys):
    """As ``marionette app`` does: it used to serve on the next free port."""
    import socket

    from marionette.cli import main

    anim = _animation(n=20, t_count=2)
    write_splat_animation(tmp_path / "a.npz", anim.gaussians, anim.trajectory, anim.fps)
    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        with pytest.raises(InputError, match=f"port {port} is in use"):
            serve(anim, port=port)
        assert main(["view", str(tmp_path / "a.npz"), "--port", str(port)]) == 2
    assert capsys.readouterr().err.strip() == f"error: port {port} is in use; --port 0 picks a free one"


def _magenta(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of the object's hue, faded or not (nothing in viser's page is magenta)."""
    r, g, b = (image[..., i].astype(int) for i in range(3))
    return (r - g > 60) & (b - g > 60) & (np.abs(r - b) < 40)


def _column(image: np.ndarray) -> float:
    """Mean column of the object's pixels (NaN when there are none)."""
    cols = np.nonzero(_magenta(image))[1]
    return cols.mean() if len(cols) else np.nan


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium (apt-get install -y chromium)")
def test_chromium_draws_the_object_and_follows_the_time(tmp_path):
    anim = _animation(n=3000, t_count=6, shift=0.6)
    viewer = serve(anim, port=0, autoplay=False)
    try:
        with browser(viewer.url) as (wait, _):
            # The ball (radius ~0.7 seen from 1.6 units, vertical fov 75°) covers ~20 % of the view.
            first = wait(lambda image: _magenta(image).mean() > 0.1)
            x0 = _column(first)
            viewer.show(5)  # the open page must follow: the ball slides right (+x)
            last = wait(lambda image: _column(image) > x0 + 40)
    finally:
        viewer.stop()
    cv2.imwrite(str(tmp_path / "first.png"), first[..., ::-1])
    cv2.imwrite(str(tmp_path / "last.png"), last[..., ::-1])
    assert _magenta(first).mean() > 0.1 and _magenta(last).mean() > 0.1
    assert abs(x0 - first.shape[1] / 2) < 60  # the first view is centred on the object
    assert _column(last) > x0 + 40

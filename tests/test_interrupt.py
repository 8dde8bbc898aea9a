"""Ctrl-C in the middle of a run leaves no partial file and keeps the user's earlier outputs."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from marionette.errors import InputError
from marionette.io import write_ply
from marionette.pipeline import write_ply_frames
from marionette.trajectory import Trajectory


def test_ctrl_c_while_rendering_leaves_nothing_partial(tmp_path, prior_file, target_png):
    out = tmp_path / "out.mp4"
    out.write_bytes(b"an earlier result")
    before = sorted(p.name for p in tmp_path.iterdir())
    cmd = [sys.executable, "-m", "marionette.cli", "transfer", str(prior_file), str(target_png), "-o", str(out),
           "--frames", "400", "--size", "256x256", "--ply-dir", str(tmp_path / "plys"),
           "--preview", str(tmp_path / "p.gif")]
    # A session of its own, so the signal reaches the whole group (ffmpeg too), as Ctrl-C in a terminal does.
    # SIGINT restored to its default: a shell running the tests in the background ignores it, which children
    # inherit (and Python then installs no KeyboardInterrupt handler).
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not any(p.name.startswith(".out.") for p in tmp_path.iterdir()):  # the video is being written
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.poll() else "slow"
        time.sleep(0.05)
    time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "error: interrupted"
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert out.read_bytes() == b"an earlier result"


def test_ply_frames_folder_is_replaced_only_when_complete(tmp_path):
    from marionette.gaussians import Gaussians

    g = Gaussians.from_rgb(np.zeros((4, 3)) + [0, 0, 3], np.full((4, 3), 0.5), np.full(4, 0.1), 0.9)
    folder = tmp_path / "plys"
    trajectory = Trajectory(np.repeat(g.means[None], 3, axis=0), np.tile(np.eye(3), (3, 1, 1, 1)), np.zeros(4))
    write_ply_frames(folder, g, trajectory)
    assert sorted(p.name for p in folder.iterdir()) == ["00000.ply", "00001.ply", "00002.ply"]

    class Broken(Trajectory):
        def frame(self, gaussians, t):
            if t == 1:
                raise KeyboardInterrupt
            return super().frame(gaussians, t)

    shorter = Broken(trajectory.means[:2], trajectory.part_rotations[:2], trajectory.labels)
    with pytest.raises(KeyboardInterrupt):
        write_ply_frames(folder, g, shorter)
    assert sorted(p.name for p in folder.iterdir()) == ["00000.ply", "00001.ply", "00002.ply"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plys"]
    write_ply(folder / "mine.ply", g)  # something of the user's: never replaced
    with pytest.raises(InputError, match="mine.ply"):
        write_ply_frames(folder, g, trajectory)


def test_ctrl_c_wrapped_by_a_compiled_library_is_still_an_interrupt(monkeypatch, capsys):
    from marionette import cli

    def wrapped(*args, **kwargs):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise SystemError("returned a result with an exception set") from e  # as numba's unpickler does

    monkeypatch.setattr(cli, "app", wrapped)
    assert cli.main(["demo"]) == 130
    assert capsys.readouterr().err.strip() == "error: interrupted"

    def bug(*args, **kwargs):
        raise ValueError("a bug")

    monkeypatch.setattr(cli, "app", bug)
    with pytest.raises(ValueError):  # a bug is not reported as an interrupt
        cli.main(["demo"])

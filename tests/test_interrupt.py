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


@pytest.mark.parametrize("signum, group", [(signal.SIGINT, True), (signal.SIGTERM, False)], ids=["ctrl-c", "kill"])
def test_an_interrupt_while_rendering_leaves_nothing_partial(tmp_path, prior_file, target_png, signum, group):
    """Ctrl-C (SIGINT to the process group, ffmpeg too) and ``kill`` (SIGTERM to the command alone) alike."""
    out = tmp_path / "out.mp4"
    out.write_bytes(b"an earlier result")
    before = sorted(p.name for p in tmp_path.iterdir())
    cmd = [sys.executable, "-m", "marionette.cli", "transfer", str(prior_file), str(target_png), "-o", str(out),
           "--frames", "150", "--size", "256x256", "--ply-dir", str(tmp_path / "plys"),
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
    (os.killpg if group else os.kill)(proc.pid, signum)
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


def test_ctrl_c_in_the_report_stage_leaves_none_of_the_outputs(tmp_path, target_png, monkeypatch, capsys):
    """Every output of a command is one unit: an interrupt late in `run` puts none of them in place."""
    from test_cli import write_clip

    from marionette import cli
    from marionette.synthetic import make_scene

    frames, masks = write_clip(tmp_path, make_scene("inplane", num_frames=8, size=(96, 72), seed=2))
    out, plot = tmp_path / "out.mp4", tmp_path / "plot.png"
    out.write_bytes(b"an earlier result")
    plot.write_bytes(b"my own plot")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    folders = sorted(p.name for p in tmp_path.iterdir() if p.is_dir())

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("marionette.eval.run_report", interrupted)
    code = cli.main(["run", str(frames), str(target_png), "--masks", str(masks), "-o", str(out), "-q",
                     "--plot", str(plot), "--side-by-side", str(tmp_path / "sbs.mp4"),
                     "--report", str(tmp_path / "report.json"), "--preview", str(tmp_path / "p.gif"),
                     "--splats", str(tmp_path / "s.npz"), "--ply-dir", str(tmp_path / "plys")])
    assert code == 130
    assert capsys.readouterr().err.strip().splitlines() == ["error: interrupted"]
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_dir()) == folders


def test_staged_outputs_are_put_in_place_together_or_not_at_all(tmp_path):
    from marionette.io.atomic import staged_outputs

    (tmp_path / "a.txt").write_text("old a")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("the user's")
    (tmp_path / "mine" / "x.csv").write_text("old x")
    with pytest.raises(KeyboardInterrupt), staged_outputs() as outputs:
        outputs.file(tmp_path / "a.txt").write_text("new a")
        outputs.file(tmp_path / "b.txt").write_text("new b")
        raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "mine"]
    assert (tmp_path / "a.txt").read_text() == "old a"

    with staged_outputs() as outputs:
        a, b = outputs.file(tmp_path / "a.txt"), outputs.file(tmp_path / "b.txt")
        a.write_text("new a")
        b.write_text("new b")
        (outputs.folder(tmp_path / "mine") / "x.csv").write_text("new x")
        assert (tmp_path / "a.txt").read_text() == "old a" and not (tmp_path / "b.txt").exists()  # not yet
    assert (tmp_path / "a.txt").read_text() == "new a" and (tmp_path / "b.txt").read_text() == "new b"
    assert {p.name: p.read_text() for p in (tmp_path / "mine").iterdir()} == {"notes.txt": "the user's",
                                                                              "x.csv": "new x"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt", "mine"]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_an_interrupt_in_a_stage_is_raised_at_its_next_progress_call_not_where_it_lands(signum):
    from marionette import progress
    from marionette.progress import Reporter, sigterm_as_interrupt

    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)  # a background shell may ignore it
    try:
        reporter = Reporter(quiet=True)
        reached = []
        with sigterm_as_interrupt(), pytest.raises(KeyboardInterrupt):  # as main() runs every command
            with reporter.stage("work", 3) as step:
                step(1, 3)
                os.kill(os.getpid(), signum)
                time.sleep(0.05)  # the handler has run: had it raised, the next line would not
                reached.append("after the signal")
                step(2, 3)
                reached.append("after the next progress call")
        assert reached == ["after the signal"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored after the stage
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # and SIGTERM after the command
        assert not progress.interrupt_requested()  # raised once: the next stage runs
        with reporter.stage("more", 1) as step:
            step(1, 1)
    finally:
        signal.signal(signal.SIGINT, inherited)

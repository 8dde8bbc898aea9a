"""Command line: contract behaviour, errors as one line with exit code 2, no partial outputs."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from marionette.camera import Camera
from marionette.cli import _prior_line, main
from marionette.gaussians import Gaussians
from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.io import read_ply, read_prior, read_video, write_ply
from marionette.prior import SpatPrior

pytestmark = pytest.mark.heavy


def one_error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def test_transfer_writes_a_video_of_the_right_length(tmp_path, prior_file, target_png):
    out = tmp_path / "out.mp4"
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(out), "--quiet"]) == 0
    video = read_video(out)
    assert video.frames.shape[:3] == (8, 64, 64) and video.fps == pytest.approx(12.0)
    # The square turns in the image plane: the last frame differs from the first.
    assert np.abs(video.frames[-1].astype(int) - video.frames[0]).mean() > 2


def test_transfer_speed_and_frames(tmp_path, prior_file, target_png):
    out = tmp_path / "out.gif"
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(out), "--speed", "0.5",
                 "--frames", "5", "--fps", "5", "-q"]) == 0
    assert read_video(out).frames.shape[0] == 5


def test_transfer_controls_and_per_frame_ply(tmp_path, prior_file, target_png):
    out, plys = tmp_path / "out.mp4", tmp_path / "plys"
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(out), "-q", "--frames", "12",
                 "--loop", "pingpong", "--reverse", "--rotation-scale", "2", "--camera", "dolly", "--anchor", "world",
                 "--ply-dir", str(plys)]) == 0
    assert read_video(out).frames.shape[0] == 12
    files = sorted(plys.glob("*.ply"))
    assert len(files) == 12 and files[0].name == "00000.ply"
    assert not np.allclose(read_ply(files[0]).means, read_ply(files[-1]).means, atol=1e-3)


def test_target_mask_file_selects_the_object(tmp_path, target_png):
    from marionette import pipeline

    mask = np.zeros((64, 64), np.uint8)
    mask[20:44, 16:32] = 255  # the left half of the square only
    cv2.imwrite(str(tmp_path / "mask.png"), mask)
    whole = pipeline.load_target(target_png)
    half = pipeline.load_target(target_png, mask=tmp_path / "mask.png")
    assert half.mask.sum() == (mask > 0).sum() and half.mask.sum() < 0.6 * whole.mask.sum()


def test_render_command(tmp_path):
    g = Gaussians.from_rgb(np.array([[0.0, 0.0, 3.0]]), np.array([[1.0, 0.0, 0.0]]), np.array([0.3]), 0.99)
    write_ply(tmp_path / "scene.ply", g)
    cam = Camera.from_fov(40, 30)
    (tmp_path / "cam.json").write_text(json.dumps(cam.to_dict()))
    out = tmp_path / "img.png"
    assert main(["render", str(tmp_path / "scene.ply"), "--camera", str(tmp_path / "cam.json"),
                 "-o", str(out), "--background", "0,0,0"]) == 0
    img = cv2.imread(str(out))[..., ::-1]
    assert img.shape == (30, 40, 3)
    assert tuple(img[15, 20]) == pytest.approx((255, 0, 0), abs=40) and tuple(img[0, 0]) == (0, 0, 0)


@pytest.mark.parametrize("args, words", [
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--speed", "0"], "--speed"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--frames", "-3"], "--frames"),
    (["transfer", "{prior}", "{target}", "-o", "{tmp}/x.avi"], "unsupported video output"),
    (["transfer", "{prior}", "{target}", "-o", "{frames}/0.png/out.mp4"], "does not exist"),
    (["transfer", "{tmp}/nope.npz", "{target}", "-o", "{out}"], "does not exist"),
    (["transfer", "{target}", "{target}", "-o", "{out}"], "not a readable .npz"),
    (["transfer", "{prior}", "{tmp}/nope.png", "-o", "{out}"], "nope.png"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--background", "red"], "--background"),
    (["extract", "{tmp}/novideo.mp4", "-o", "{tmp}/p.npz"], "novideo.mp4"),
    (["extract", "{target}", "-o", "{tmp}/p.npz", "--parts", "zero"], "--parts"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--stride", "0"], "stride"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--start", "50"], "selected range"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--smooth", "-1"], "--smooth"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--plot", "{tmp}/plot.jpg"], "--plot"),
    (["extract", "{frames}", "-o", "{out}"], "--output must name a .npz file"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--masks", "{tmp}/nomasks"], "nomasks"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--depth", "{tmp}/nodepth"], "nodepth"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--focal", "wide"], "--focal must be 'auto' or a positive"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--focal", "0"], "--focal must be 'auto' or a positive"),
    (["eval-self", "{frames}", "-o", "{tmp}/e", "--focal", "-5"], "--focal must be 'auto' or a positive"),
    (["render", "{tmp}/none.ply", "--camera", "{tmp}/none.json", "-o", "{tmp}/i.png"], "none.json"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--loop", "bounce"], "--loop"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--anchor", "moon"], "--anchor"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--shape", "sphere"], "--shape must be auto or one of"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--polish", "-2"], "--polish"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--part-seed", "1-3"], "--part-seed"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--part-seed", "1:3,4"], "part seed for part 1"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--target-mask", "{tmp}/nomask.png"], "nomask.png"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--camera", "crane"], "--camera"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--camera", "orbit", "--camera-path", "{prior}"], "exclude"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--camera-path", "{tmp}/none.json"], "none.json"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--rotation-scale", "nan"], "--rotation-scale"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--camera", "dolly", "--camera-amount", "2"], "dolly"),
    (["transfer", "{prior}", "{target}", "-o", "{out}", "--camera", "orbit", "--camera-amount", "1e9"], "orbit"),
    (["transfer", "{prior}"], "Missing"),
    (["frobnicate"], "No such command"),
])
def test_bad_input_is_one_error_line_and_exit_2(tmp_path, capsys, prior_file, target_png, args, words):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(3):
        cv2.imwrite(str(frames / f"{i}.png"), np.full((24, 32, 3), 40 * i, np.uint8))
    fill = {"prior": prior_file, "target": target_png, "out": tmp_path / "out.mp4", "tmp": tmp_path, "frames": frames}
    code = main([a.format(**fill) for a in args])
    line = one_error_line(capsys)
    assert code == 2 and words in line
    assert not (tmp_path / "out.mp4").exists() and not (tmp_path / "p.npz").exists()
    assert not list(tmp_path.glob(".*tmp*"))


def test_existing_output_survives_a_failed_run(tmp_path, capsys, prior_file):
    out = tmp_path / "out.mp4"
    out.write_bytes(b"precious")
    transparent = tmp_path / "clear.png"
    cv2.imwrite(str(transparent), np.zeros((32, 32, 4), np.uint8))
    assert main(["transfer", str(prior_file), str(transparent), "-o", str(out)]) == 2
    assert "transparent" in one_error_line(capsys)
    assert out.read_bytes() == b"precious"


@pytest.mark.parametrize("command", [[sys.executable, "-m", "marionette"],
                                     [str(Path(sys.executable).with_name("marionette"))]])
def test_no_command_prints_the_help_and_exits_2_as_click_does(command):
    proc = subprocess.run(command, capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    assert "Usage: marionette" in proc.stdout and "extract" in proc.stdout
    assert proc.stderr == ""  # no traceback, and no error line: the help says it all


def test_the_help_loads_no_stage_of_the_method():
    """The command line imports a stage (and numba, SciPy, ONNX Runtime) when a command runs it, not for --help."""
    code = ("import sys\nfrom marionette.cli import main\ncode = main(['extract', '--help'])\n"
            "print(code, sorted(m for m in ('numba', 'scipy', 'onnxruntime', 'marionette.pipeline', "
            "'marionette.source') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == "0 []"


def test_render_warns_when_nothing_of_the_scene_is_in_view(tmp_path, capsys):
    g = Gaussians.from_rgb(np.array([[0.0, 0.0, -3.0], [0.2, 0.0, -3.0]]), np.array([[1.0, 0.0, 0.0]] * 2),
                           np.array([0.3, 0.3]), 0.99)  # behind a camera at the origin looking along +z
    write_ply(tmp_path / "scene.ply", g)
    (tmp_path / "cam.json").write_text(json.dumps(Camera.from_fov(40, 30).to_dict()))
    out = tmp_path / "img.png"
    assert main(["render", str(tmp_path / "scene.ply"), "--camera", str(tmp_path / "cam.json"), "-o", str(out),
                 "--json", "-q"]) == 0
    captured = capsys.readouterr()
    (warning,) = json.loads(captured.out)["warnings"]
    assert "nothing of the scene is in view" in warning and "2 of them behind the camera" in warning
    assert captured.err.strip().splitlines() == [f"warning: {warning}"]
    assert (cv2.imread(str(out)) == 255).all()  # the image is written: the background alone
    (tmp_path / "front.json").write_text(json.dumps(Camera.from_fov(40, 30).with_pose(
        make_transform(axis_angle_to_matrix([0, np.pi, 0]), [0, 0, 0])).to_dict()))
    assert main(["render", str(tmp_path / "scene.ply"), "--camera", str(tmp_path / "front.json"), "-o", str(out),
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []  # turned around, it sees them


def test_installed_entry_point_prints_no_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "marionette", "transfer", str(tmp_path / "a.npz"),
                           str(tmp_path / "b.png"), "-o", str(tmp_path / "c.mp4")], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: ") and "Traceback" not in proc.stderr


def write_clip(root, scene):
    """A scene as ``root/frames`` (PNG frames) and ``root/masks`` (PNG masks); the two folders."""
    from marionette.io import write_video

    frames, masks = root / "frames", root / "masks"
    write_video(frames, scene.frames, scene.fps)
    masks.mkdir()
    for i, m in enumerate(scene.masks):
        cv2.imwrite(str(masks / f"{i:05d}.png"), m.astype(np.uint8) * 255)
    return frames, masks


def test_extract_and_run_on_a_synthetic_video(tmp_path, target_png, capsys):
    from marionette.synthetic import make_scene

    scene = make_scene("inplane", num_frames=10, size=(160, 120), seed=1)
    frames, masks = write_clip(tmp_path, scene)
    assert main(["extract", str(frames), "--masks", str(masks), "-o", str(tmp_path / "p.npz"), "-q",
                 "--parts", "1", "--plot", str(tmp_path / "p.png")]) == 0
    prior = read_prior(tmp_path / "p.npz")
    assert prior.num_frames == 10 and prior.num_parts == 1
    assert cv2.imread(str(tmp_path / "p.png")).shape[0] > 100
    capsys.readouterr()
    assert main(["extract", str(frames), "--masks", str(masks), "-o", str(tmp_path / "q.npz"), "--verbose",
                 "--parts", "1", "--start", "2", "--stride", "2", "--no-recover-frames", "--strict-tracks"]) == 0
    assert "tracks: strict; " in capsys.readouterr().err
    assert main(["extract", str(frames), "--masks", str(masks), "-o", str(tmp_path / "f.npz"), "-q",
                 "--focal", "auto"]) == 0
    focal = read_prior(tmp_path / "f.npz").metadata["focal"]
    # An in-plane turn leaves no trace of the focal length: the default (60° wide) is kept, and said so.
    assert not focal["measured"] and focal["focal_px"] == pytest.approx(prior.intrinsics[0, 0], abs=0.01)
    part = read_prior(tmp_path / "q.npz")
    assert part.num_frames == 4 and part.fps == pytest.approx(prior.fps / 2)
    assert prior.metadata["options"]["recover_frames"] and not part.metadata["options"]["recover_frames"]
    assert part.metadata["options"]["strict_tracks"] is True and prior.metadata["options"]["strict_tracks"] == "auto"
    assert part.metadata["tracks"]["strict"] and 0 < prior.metadata["tracks"]["anchor_match"] <= 1  # tried
    assert main(["run", str(frames), str(target_png), "--masks", str(masks), "-o", str(tmp_path / "r.mp4"),
                 "-q"]) == 0
    assert read_video(tmp_path / "r.mp4").frames.shape[0] == 10


def test_a_frame_posed_after_the_refinement_is_listed_and_said(tmp_path, capsys, monkeypatch):
    # PnP fails once at frame 6 in the sequential pass; tried again after the refinement, it is placed: listed
    # among the recovered frames with its own note, and --verbose says how.
    from marionette.source import rigid
    from marionette.synthetic import make_scene

    frames, masks = write_clip(tmp_path, make_scene("inplane", num_frames=12, size=(160, 120), seed=1))
    pnp, calls = rigid._pnp, []

    def lost_once_at_frame_6(points, uv, k, guess, options):
        calls.append(len(points))
        if len(calls) == 6:
            return None, np.zeros(len(points), bool), "PnP RANSAC found 0 inliers, need 6"
        return pnp(points, uv, k, guess, options)

    monkeypatch.setattr(rigid, "_pnp", lost_once_at_frame_6)
    assert main(["extract", str(frames), "--masks", str(masks), "-o", str(tmp_path / "p.npz"), "--verbose",
                 "--parts", "1", "--no-recover-frames"]) == 0
    meta = read_prior(tmp_path / "p.npz").metadata
    assert meta["failed_frames"] == {} and list(meta["recovered_frames"]) == ["0:6"]
    assert meta["recovered_frames"]["0:6"].startswith(rigid.RETRIED_NOTE)
    assert "1 part-frames the tracks lost were recovered by PnP after the refinement: 0:6" in capsys.readouterr().err


def test_demo_writes_its_videos(tmp_path):
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "--quiet"]) == 0
    for name in ("source.mp4", "result.mp4", "side_by_side.mp4", "prior.npz", "target.png"):
        assert (out / name).stat().st_size > 0, name
    result = read_video(out / "result.mp4")
    assert result.frames.shape[0] == read_video(out / "source.mp4").frames.shape[0]


def test_the_extracted_motion_is_summed_up_in_one_line():
    t = 5
    turning = [make_transform(axis_angle_to_matrix([0, np.radians(22.5) * i, 0]), [0, 0, 0]) for i in range(t)]
    poses = np.stack([np.tile(np.eye(4), (t, 1, 1)), np.array(turning)])
    centres = np.zeros((2, t, 3))
    centres[1, :, 0] = np.arange(t) * 0.5  # 2 units in all, the part radius 2 → 1 radius
    prior = SpatPrior.from_poses(poses, centres, np.array([1.0, 2.0]), fps=10.0, image_size=(64, 48),
                                 intrinsics=np.eye(3))
    line = _prior_line(prior)
    assert line == "motion: 2 parts over 5 frames; part 0 static; part 1 turns up to 90.0° and travels 1.00 radii"


@pytest.fixture
def user_files(tmp_path, prior_file, target_png):
    """The inputs of every kind one folder might hold: a video, a frame and a mask folder, a prior, a photo, a
    camera path, a config and a job file."""
    from marionette.io import write_video

    frames, masks = tmp_path / "frames", tmp_path / "masks"
    for folder in (frames, masks):
        folder.mkdir()
        for i in range(3):
            cv2.imwrite(str(folder / f"{i:05d}.png"), np.full((24, 32, 3), 40 * i, np.uint8))
    write_video(tmp_path / "src.mp4", np.zeros((3, 24, 32, 3), np.uint8), 10.0)
    (tmp_path / "cams.json").write_text("[]")
    (tmp_path / "look.toml").write_text("")
    (tmp_path / "jobs.toml").write_text("")
    return {"tmp": tmp_path, "prior": prior_file, "target": target_png, "frames": frames, "masks": masks}


def _tree(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else None for p in sorted(folder.rglob("*"))}


@pytest.mark.parametrize("args, words", [
    (["run", "{tmp}/src.mp4", "{target}", "-o", "{tmp}/src.mp4"], "--output {tmp}/src.mp4 is also SOURCE"),
    (["run", "{tmp}/src.mp4", "{target}", "-o", "{tmp}/./frames/../src.mp4"], "is also SOURCE {tmp}/src.mp4"),
    (["run", "{frames}", "{target}", "-o", "{frames}/out.mp4"], "--output {frames}/out.mp4 is inside SOURCE"),
    (["run", "{frames}", "{target}", "-o", "{tmp}/o.mp4", "--ply-dir", "{tmp}"], "--ply-dir {tmp} holds SOURCE"),
    (["run", "{frames}", "{target}", "-o", "{tmp}/o.mp4", "--report", "{tmp}/look.toml", "--config",
      "{tmp}/look.toml"], "--report {tmp}/look.toml is also --config"),
    (["run", "{frames}", "{target}", "-o", "{tmp}/o.mp4", "--side-by-side", "{target}"], "is also TARGET"),
    (["run", "{frames}", "{target}", "-o", "{tmp}/o.mp4", "--target-depth", "{tmp}/d.npy", "--plot",
      "{tmp}/d.npy"], "--plot {tmp}/d.npy is also --target-depth"),
    (["transfer", "{prior}", "{target}", "-o", "{tmp}/o.mp4", "--preview", "{target}"], "--preview"),
    (["transfer", "{prior}", "{target}", "-o", "{tmp}/o.mp4", "--splats", "{prior}"], "is also PRIOR"),
    (["transfer", "{prior}", "{target}", "-o", "{tmp}/cams.json", "--camera-path", "{tmp}/cams.json"],
     "is also --camera-path"),
    (["transfer", "{prior}", "{target}", "-o", "{tmp}/o.gif", "--preview", "{tmp}/o.gif"], "is also --preview"),
    (["transfer", "{prior}", "{target}", "-o", "{tmp}/o.mp4", "--target-mask", "{masks}/00000.png", "--ply-dir",
      "{masks}/00000.png"], "--ply-dir {masks}/00000.png is also --target-mask"),
    (["extract", "{frames}", "-o", "{tmp}/p.npz", "--save-masks", "{frames}"], "--save-masks {frames} is also SOURCE"),
    (["extract", "{frames}", "--masks", "{masks}", "-o", "{tmp}/p.npz", "--save-masks", "{masks}"], "--masks"),
    (["extract", "{frames}", "--depth", "{masks}", "-o", "{masks}/p.npz"], "is inside --depth"),
    (["reconstruct", "{frames}", "--prior", "{prior}", "-o", "{prior}"], "is also --prior"),
    (["eval-self", "{frames}", "-o", "{tmp}"], "--output {tmp} holds SOURCE {frames}"),
    (["render", "{tmp}/s.ply", "--camera", "{tmp}/cams.json", "-o", "{tmp}/s.ply"], "is also SCENE"),
    (["batch", "{tmp}/jobs.toml", "-o", "{tmp}/jobs.toml"], "is also JOBS"),
])
def test_an_output_that_is_an_input_is_refused_and_nothing_is_touched(user_files, capsys, args, words):
    tmp = user_files["tmp"]
    before = _tree(tmp)
    assert main([a.format(**user_files) for a in args]) == 2
    line = one_error_line(capsys)
    assert words.format(**user_files) in line and "give it a path of its own" in line
    assert _tree(tmp) == before


def test_missing_output_folders_are_made_and_removed_again_if_the_command_fails(tmp_path, prior_file, target_png,
                                                                                capsys):
    out = tmp_path / "new" / "deeper" / "out.mp4"
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(out), "--preview",
                 str(tmp_path / "previews" / "o.gif"), "-q"]) == 0
    assert out.is_file() and (tmp_path / "previews" / "o.gif").is_file()
    clear = tmp_path / "clear.png"
    cv2.imwrite(str(clear), np.zeros((32, 32, 4), np.uint8))
    before = _tree(tmp_path)
    assert main(["transfer", str(prior_file), str(clear), "-o", str(tmp_path / "a" / "b" / "out.mp4"), "--ply-dir",
                 str(tmp_path / "new" / "plys" / "frames")]) == 2
    assert "transparent" in one_error_line(capsys)
    assert _tree(tmp_path) == before  # the folders made for the outputs are gone again, the others stay
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(clear / "x" / "out.mp4")]) == 2
    assert one_error_line(capsys) == f"error: cannot make output folder {clear / 'x'}: Not a directory"


@pytest.mark.parametrize("name, image", [("tiny", np.full((6, 40, 3), 200, np.uint8)), ("corrupt", None),
                                         ("blank", np.full((300, 400, 3), 128, np.uint8))])
def test_run_checks_the_target_before_it_reads_the_source(tmp_path, capsys, monkeypatch, name, image):
    from marionette import pipeline

    def never(*args, **kwargs):
        raise AssertionError("the source was read before the target was checked")

    monkeypatch.setattr(pipeline, "open_video", never)
    monkeypatch.setattr(pipeline, "read_video", never)
    target = tmp_path / f"{name}.png"
    if image is None:
        target.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    else:
        cv2.imwrite(str(target), image)
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(3):
        cv2.imwrite(str(frames / f"{i}.png"), np.full((24, 32, 3), 40 * i, np.uint8))
    assert main(["run", str(frames), str(target), "-o", str(tmp_path / "o.mp4")]) == 2
    assert f"{name}.png" in one_error_line(capsys)


def test_with_json_an_error_is_also_a_json_object_on_stdout(tmp_path, prior_file, target_png, capsys, monkeypatch):
    import marionette.cli

    assert main(["transfer", str(tmp_path / "none.npz"), str(target_png), "-o", str(tmp_path / "o.mp4"),
                 "--json"]) == 2
    captured = capsys.readouterr()
    (line,) = captured.err.splitlines()
    assert json.loads(captured.out) == {"command": "transfer", "error": line.removeprefix("error: "), "exit_code": 2}
    assert main(["extract", "--json", "--frobnicate"]) == 2  # a usage error
    assert json.loads(capsys.readouterr().out)["error"].startswith("No such option: --frobnicate")
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(tmp_path / "o.mp4")]) == 0
    assert capsys.readouterr().out == ""  # without --json, nothing on stdout

    def interrupted(path):
        raise KeyboardInterrupt

    monkeypatch.setattr(marionette.cli, "read_prior", interrupted)
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(tmp_path / "o.mp4"), "--json", "-q"]) == 130
    captured = capsys.readouterr()
    assert json.loads(captured.out) == {"command": "transfer", "error": "interrupted", "exit_code": 130}
    assert captured.err == "error: interrupted\n"


def _commands():
    from typer.main import get_command

    from marionette.cli import app

    group = get_command(app)
    return [(None, group)] + list(group.commands.items())


def test_the_help_groups_every_option_in_a_panel_and_shows_whole_names_at_80_columns(capsys, monkeypatch):
    from marionette.cli import PANELS

    monkeypatch.setenv("COLUMNS", "80")
    for name, command in _commands():
        assert main(([name] if name else []) + ["--help"]) == 0
        shown = capsys.readouterr().out
        lines = shown.splitlines()
        assert max(len(line) for line in lines) <= 80 and "…" not in shown and "<bool>" not in shown, name
        assert any(line.split()[:3] == ["│", "--help", "Show"] for line in lines)  # no value after --help
        for param in command.params:
            if param.param_type_name == "option":
                assert param.rich_help_panel in PANELS, (name, param.name)
                assert len(param.help) <= 72, (name, param.name)
                for option in param.opts + param.secondary_opts:  # whole, as a word of the help
                    assert f" {option} " in shown, (name, option)
        if name == "run":
            assert len(lines) < 349 // 2  # 349 lines before the options were grouped and shortened


def test_the_command_reference_pages_are_current():
    from marionette.cli_docs import FOLDER, pages

    expected = pages()
    assert {p.name for p in FOLDER.glob("*.md")} == set(expected), "run `python -m marionette.cli_docs`"
    for name, text in expected.items():
        assert (FOLDER / name).read_text(encoding="utf-8") == text, \
            f"docs/commands/{name} is out of date: run `python -m marionette.cli_docs`"


def test_verbose_says_how_each_part_moves_on_its_joint():
    from marionette.cli import _joint_line

    slider = {"model": "slider", "on_part": 0, "axis": [0.41, 0.46, -0.78], "range": [0.0, 0.6137],
              "residual_px": 0.23, "free_residual_px": 0.25, "dropped_tracks": 3}
    assert _joint_line(slider) == ("a slider on part 0 along (0.41, 0.46, -0.78), travelling 0.000 to 0.614 in the "
                                   "poses' units (0.23 px against 0.25 px free)")
    hinge = {"model": "hinge", "on_part": 1, "axis": [1.0, 0.0, 0.0], "point": [0, 0, 5], "range_deg": [0.0, 72.5],
             "residual_px": 0.3, "free_residual_px": 0.4, "dropped_tracks": 0}
    assert "a hinge on part 1 along (1.00, 0.00, 0.00), turning 0.0° to 72.5°" in _joint_line(hinge)
    assert _joint_line({"model": "free", "reason": "it barely moves"}) == "free: it barely moves"
    from_pixels = {"model": "hinge", "on_part": 0, "axis": [0.0, 1.0, 0.0], "point": [0, 0, 4],
                   "range_deg": [0.0, 70.0], "fitted_to": "pixels and masks", "cost_ratio": 0.31}
    assert _joint_line(from_pixels).endswith("(fitted to its pixels and the masks, 0.31 of its free poses' cost)")
    assert _joint_line({"model": "free", "reason": "no hinge fits", "pixels": "too few of its tracks placed"}) == \
        "free: no hinge fits; in its pixels: too few of its tracks placed"

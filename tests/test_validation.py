"""Validation sweep through the command line (issue 7, item 1).

Every bad input, for every command it reaches, must end with exit code 2,
exactly one ``error: …`` line on stderr and nothing written: the output
folder is left as it was (no output, no temporary file).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from marionette.camera import Camera
from marionette.cli import main
from marionette.gaussians import Gaussians
from marionette.io import write_ply, write_prior, write_video
from marionette.synthetic import make_scene


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Small valid inputs of every kind, and bad variants of them, in one folder."""
    d = tmp_path_factory.mktemp("inputs")
    scene = make_scene("inplane", num_frames=6, size=(64, 48), seed=2)
    write_video(d / "frames", scene.frames, scene.fps)
    write_prior(d / "prior.npz", scene.ground_truth_prior())

    def write_masks(name, masks):
        (d / name).mkdir()
        for i, m in enumerate(masks):
            cv2.imwrite(str(d / name / f"{i:05d}.png"), m.astype(np.uint8) * 255)

    write_masks("masks", scene.masks)
    write_masks("masks_empty", np.zeros_like(scene.masks))
    write_masks("masks_short", scene.masks[:4])
    write_masks("masks_size", np.zeros((6, 30, 50), bool) | True)
    write_masks("masks_first_empty", np.concatenate([np.zeros_like(scene.masks[:1]), scene.masks[1:]]))
    (d / "one_frame").mkdir()
    cv2.imwrite(str(d / "one_frame" / "0.png"), scene.frames[0])
    (d / "corrupt_frame").mkdir()
    for i in range(3):
        cv2.imwrite(str(d / "corrupt_frame" / f"{i}.png"), scene.frames[i])
    (d / "corrupt_frame" / "1.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    (d / "garbage.mp4").write_bytes(os.urandom(2000))
    (d / "clip.xyz").write_bytes(b"data")

    target = np.zeros((48, 48, 4), np.uint8)
    target[12:36, 12:36] = (200, 60, 30, 255)
    cv2.imwrite(str(d / "target.png"), cv2.cvtColor(target, cv2.COLOR_RGBA2BGRA))
    cv2.imwrite(str(d / "clear.png"), np.zeros((48, 48, 4), np.uint8))
    cv2.imwrite(str(d / "empty_mask.png"), np.zeros((48, 48), np.uint8))
    (d / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + os.urandom(200))
    (d / "target.webp").write_bytes(b"RIFF")
    cv2.imwrite(str(d / "tiny.png"), np.full((6, 48, 3), 200, np.uint8))

    g = Gaussians.from_rgb(np.array([[0.0, 0.0, 3.0], [0.2, 0, 3]]), np.full((2, 3), 0.5), np.array([0.3, 0.2]))
    write_ply(d / "scene.ply", g)
    good_ply = (d / "scene.ply").read_bytes()
    end = good_ply.index(b"end_header\n") + len(b"end_header\n")
    (d / "truncated.ply").write_bytes(good_ply[:end + 10])
    (d / "absurd.ply").write_bytes(good_ply[:end].replace(b"element vertex 2", b"element vertex 1000000000000")
                                   + good_ply[end:])
    (d / "unknown_format.ply").write_bytes(good_ply.replace(b"binary_little_endian", b"binary_middle_endian"))
    (d / "no_opacity.ply").write_bytes(good_ply.replace(b"property float opacity", b"property float opaque"))
    nan = np.frombuffer(good_ply[end:], "<f4").copy()
    nan[0] = np.nan
    (d / "nan.ply").write_bytes(good_ply[:end] + nan.tobytes())

    camera = Camera.from_fov(40, 30).to_dict()
    (d / "camera.json").write_text(json.dumps(camera))
    bad_cameras = {
        "missing": {k: v for k, v in camera.items() if k != "fx"},
        "string": {**camera, "fy": "100"},
        "nan": {**camera, "cx": float("nan")},
        "huge": {**camera, "width": 10**6},
        "singular": {**camera, "world_to_camera": np.diag([1.0, 1.0, 0.0, 1.0]).tolist()},
        "scaled": {**camera, "world_to_camera": np.diag([2.0, 2.0, 2.0, 1.0]).tolist()},
        "sheared": {**camera, "world_to_camera": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]},
    }
    for name, value in bad_cameras.items():
        (d / f"camera_{name}.json").write_text(json.dumps(value))
    (d / "camera_path_count.json").write_text(json.dumps([camera] * 3))
    (d / "camera_path_bad.json").write_text(json.dumps([camera, bad_cameras["scaled"]] + [camera] * 4))
    (d / "not.json").write_text("{width: 40")

    with np.load(d / "prior.npz") as f:
        arrays = dict(f)
    bad_priors = {
        "format": {"format": np.array("something.else")},
        "version": {"version": np.array(99)},
        "shape": {"rotations": arrays["rotations"][:, :2]},
        "nan": {"centroids": np.full_like(arrays["centroids"], np.nan)},
        "inf": {"poses": np.where(np.eye(4, dtype=bool), np.inf, arrays["poses"])},
        "missing": {"radii": None},
        "dtype": {"image_size": arrays["image_size"].astype(np.float32)},
    }
    for name, changes in bad_priors.items():
        bad = {**arrays, **changes}
        np.savez(d / f"prior_{name}.npz", **{k: v for k, v in bad.items() if v is not None})
    np.savez(d / "prior_pickle.npz", **arrays, labels=np.array([{"x": 1}], dtype=object))
    (d / "prior_truncated.npz").write_bytes((d / "prior.npz").read_bytes()[:300])
    (d / "prior_text.npz").write_text("not a zip")
    return d


TRANSFER = ["transfer", "{in}/prior.npz", "{in}/target.png", "-o", "{out}/out.mp4", "-q"]
RUN = ["run", "{in}/frames", "{in}/target.png", "--masks", "{in}/masks", "-o", "{out}/out.mp4", "-q"]
EXTRACT = ["extract", "{in}/frames", "--masks", "{in}/masks", "-o", "{out}/prior.npz", "-q"]
RENDER = ["render", "{in}/scene.ply", "--camera", "{in}/camera.json", "-o", "{out}/image.png"]


def replace(command: list[str], old: str, new: str) -> list[str]:
    assert old in command, (old, command)
    return [new if a == old else a for a in command]


CASES = {
    # missing, unreadable, corrupt or unsupported inputs
    "extract missing source": (replace(EXTRACT, "{in}/frames", "{in}/nothing"), "does not exist"),
    "extract corrupt video": (replace(EXTRACT, "{in}/frames", "{in}/garbage.mp4"), "cannot read video"),
    "extract unsupported format": (replace(EXTRACT, "{in}/frames", "{in}/clip.xyz"), "unsupported video format"),
    "extract one frame": (replace(EXTRACT, "{in}/frames", "{in}/one_frame"), "at least 2"),
    "extract corrupt frame": (EXTRACT[:1] + ["{in}/corrupt_frame", "-o", "{out}/prior.npz", "-q"], "1.png"),
    "run missing source": (replace(RUN, "{in}/frames", "{in}/nothing"), "does not exist"),
    "run one frame": (replace(RUN, "{in}/frames", "{in}/one_frame"), "at least 2"),
    "run missing target": (replace(RUN, "{in}/target.png", "{in}/nothing.png"), "does not exist"),
    "run corrupt target": (replace(RUN, "{in}/target.png", "{in}/corrupt.png"), "cannot read image"),
    "run tiny target": (replace(RUN, "{in}/target.png", "{in}/tiny.png"), "48x6 pixels"),
    # masks
    "extract masks missing": (replace(EXTRACT, "{in}/masks", "{in}/nomasks"), "does not exist"),
    "extract masks empty": (replace(EXTRACT, "{in}/masks", "{in}/masks_empty"), "empty"),
    "extract first mask empty": (replace(EXTRACT, "{in}/masks", "{in}/masks_first_empty"), "frame 0 is empty"),
    "extract masks wrong count": (replace(EXTRACT, "{in}/masks", "{in}/masks_short"), "holds 4 masks"),
    "extract masks wrong size": (replace(EXTRACT, "{in}/masks", "{in}/masks_size"), "50x30"),
    "run masks wrong count": (replace(RUN, "{in}/masks", "{in}/masks_short"), "holds 4 masks"),
    # targets
    "transfer transparent target": (replace(TRANSFER, "{in}/target.png", "{in}/clear.png"), "transparent"),
    "transfer corrupt target": (replace(TRANSFER, "{in}/target.png", "{in}/corrupt.png"), "cannot read image"),
    "transfer unsupported target": (replace(TRANSFER, "{in}/target.png", "{in}/target.webp"), "unsupported"),
    "transfer missing target": (replace(TRANSFER, "{in}/target.png", "{in}/nothing.png"), "nothing.png"),
    "transfer empty target mask": (TRANSFER + ["--target-mask", "{in}/empty_mask.png"], "empty"),
    "run transparent target": (replace(RUN, "{in}/target.png", "{in}/clear.png"), "transparent"),
    # priors
    **{f"transfer prior {name}": (replace(TRANSFER, "{in}/prior.npz", f"{{in}}/prior_{name}.npz"), words)
       for name, words in [("format", "'format'"), ("version", "'version' is 99"), ("shape", "'rotations'"),
                           ("nan", "'centroids' contains NaN"), ("inf", "'poses' contains NaN or infinite"),
                           ("missing", "lacks key 'radii'"), ("dtype", "'image_size' has dtype float32"),
                           ("pickle", "pickled"), ("truncated", "not a readable .npz"),
                           ("text", "not a readable .npz")]},
    "transfer prior missing": (replace(TRANSFER, "{in}/prior.npz", "{in}/nothing.npz"), "does not exist"),
    # PLY files, as render scenes and as transfer targets
    **{f"render ply {name}": (replace(RENDER, "{in}/scene.ply", f"{{in}}/{name}.ply"), words)
       for name, words in [("truncated", "truncated"), ("absurd", "1000000000000"), ("nothing", "does not exist"),
                           ("unknown_format", "not a valid PLY"), ("no_opacity", "'opacity'"),
                           ("nan", "NaN or infinite")]},
    **{f"transfer ply {name}": (replace(TRANSFER, "{in}/target.png", f"{{in}}/{name}.ply"), words)
       for name, words in [("truncated", "truncated"), ("nan", "NaN or infinite"), ("no_opacity", "'opacity'")]},
    # cameras
    **{f"render camera {name}": (replace(RENDER, "{in}/camera.json", f"{{in}}/camera_{name}.json"), words)
       for name, words in [("missing", "missing key 'fx'"), ("string", "'fy' must be a finite number"),
                           ("nan", "'cx' must be a finite number"), ("huge", "width must be an integer"),
                           ("singular", "not a proper rotation"), ("scaled", "not a proper rotation"),
                           ("sheared", r"[0, 0, 0, 1]")]},
    "render camera not json": (replace(RENDER, "{in}/camera.json", "{in}/not.json"), "not valid JSON"),
    "render camera missing": (replace(RENDER, "{in}/camera.json", "{in}/nothing.json"), "nothing.json"),
    "transfer camera path count": (TRANSFER + ["--camera-path", "{in}/camera_path_count.json"], "3 cameras for 6"),
    "transfer camera path bad": (TRANSFER + ["--camera-path", "{in}/camera_path_bad.json"], "camera 1"),
    # absurd options
    **{f"{cmd[0]} {' '.join(opt)}": (cmd + list(opt), opt[0])
       for cmd in (TRANSFER, RUN)
       for opt in [("--speed", "0"), ("--speed", "-2"), ("--speed", "nan"), ("--frames", "0"), ("--frames", "-5"),
                   ("--frames", "10000000"), ("--size", "100000x64"), ("--size", "8x8"), ("--fps", "0")]},
    **{f"extract {' '.join(opt)}": (EXTRACT + list(opt), opt[0].strip("-").split("-")[0])
       for opt in [("--max-side", "0"), ("--max-side", "100000"), ("--stride", "0"), ("--start", "-1"),
                   ("--smooth", "inf"), ("--parts", "0")]},
    "extract end before start": (EXTRACT + ["--start", "3", "--end", "2"], "end"),
    "transfer dolly amount": (TRANSFER + ["--camera", "dolly", "--camera-amount", "2"], "dolly"),
    "transfer orbit amount": (TRANSFER + ["--camera", "orbit", "--camera-amount", "1e9"], "orbit"),
    "render background": (RENDER + ["--background", "1,2"], "--background"),
    # outputs
    **{f"{cmd[0]} output folder is a file": (replace(cmd, cmd[cmd.index("-o") + 1],
                                                     "{in}/clip.xyz/" + cmd[cmd.index("-o") + 1].split("/")[-1]),
                                             "does not exist")
       for cmd in (TRANSFER, RUN, EXTRACT, RENDER)},
    **{f"{cmd[0]} output is an input": (replace(cmd, cmd[cmd.index("-o") + 1], "{in}/" + name), words)
       for cmd, name, words in [(TRANSFER, "target.png", "target.png is also TARGET"),
                                (RUN, "frames/out.mp4", "frames/out.mp4 is inside SOURCE"),
                                (EXTRACT, "masks", "masks is also --masks"),
                                (RENDER, "camera.json", "camera.json is also --camera")]},
    **{f"{cmd[0]} output is a folder": (replace(cmd, cmd[cmd.index("-o") + 1],
                                                "{out}/sub" + Path(cmd[cmd.index("-o") + 1]).suffix), "folder")
       for cmd in (EXTRACT, RENDER)},
    "transfer unsupported output": (replace(TRANSFER, "{out}/out.mp4", "{out}/out.avi"), "unsupported video output"),
    "render unsupported output": (replace(RENDER, "{out}/image.png", "{out}/image.webp"), "unsupported image output"),
}


#: Cases that cli.py checks only after work has started, so progress lines come before the error.
PARAMS = [pytest.param(args, words, quiet, id=f"{name}{'' if quiet else ' (progress shown)'}")
          for name, (args, words) in CASES.items() for quiet in (True, False)]


@pytest.mark.parametrize("args, words, quiet", PARAMS)
def test_bad_input_is_one_error_line_exit_2_and_no_output(tmp_path, capfd, inputs, args, words, quiet):
    out = tmp_path / "out"
    out.mkdir()
    for suffix in (".png", ".npz"):
        (out / f"sub{suffix}").mkdir()  # an output path that is a folder, with the suffix its command takes
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    code = main([a.format(**{"in": inputs, "out": out}) for a in args if quiet or a != "-q"])
    err = capfd.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert words in err[0], err[0]
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before


@pytest.mark.parametrize("command", [TRANSFER, RUN, EXTRACT, RENDER], ids=lambda c: c[0])
def test_non_writable_output_folder(tmp_path, capfd, inputs, monkeypatch, command):
    out = tmp_path / "out"
    out.mkdir()
    if os.geteuid() == 0:  # root writes anywhere: make the check see a read-only folder
        real_access = os.access
        monkeypatch.setattr(os, "access", lambda p, mode, **kw: (False if mode & os.W_OK and os.fspath(p) ==
                                                                   os.fspath(out) else real_access(p, mode, **kw)))
    else:
        out.chmod(0o500)
    try:
        code = main([a.format(**{"in": inputs, "out": out}) for a in command])
    finally:
        out.chmod(0o700)
    err = capfd.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "not writable" in err[0], err
    assert not list(out.iterdir())


def test_valid_inputs_pass(tmp_path, capfd, inputs):
    """The sweep's inputs differ from valid ones only by what each case breaks."""
    out = tmp_path / "out"
    out.mkdir()
    for command in (RENDER, TRANSFER):
        assert main([a.format(**{"in": inputs, "out": out}) for a in command]) == 0, capfd.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["image.png", "out.mp4"]

"""Determinism (issue 7, item 5): the same inputs and options give the same prior and the same frames.

Each command runs in a fresh process, the second time with one thread for
numba, OpenMP and BLAS and another hash seed, so hidden global state (RNG
seeds, thread scheduling of parallel loops, set iteration order) would show.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys

import cv2
import numba
import numpy as np
import pytest
import threadpoolctl

from marionette import pipeline
from marionette.camera import Camera
from marionette.gaussians import Gaussians
from marionette.io import write_video
from marionette.render import render
from marionette.source import ExtractOptions
from marionette.synthetic import make_scene

pytestmark = pytest.mark.heavy

ONE_THREAD = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
              "PYTHONHASHSEED": "123"}


def cli(*runs: tuple[list, dict[str, str] | None]) -> None:
    """Run each ``(arguments, environment)`` as a ``marionette`` command in its own process, all at once
    (they are independent, and the machine has cores to spare while one waits on I/O or the GIL)."""
    procs = [subprocess.Popen([sys.executable, "-m", "marionette.cli", *map(str, args), "-q"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, **(env or {})}) for args, env in runs]
    try:
        for proc in procs:
            _, err = proc.communicate(timeout=300)
            assert proc.returncode == 0, err
    finally:
        for proc in procs:
            proc.kill()
            proc.communicate()


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A hinged object, 10 frames of 128x96 with sensor noise, its masks and a target image."""
    d = tmp_path_factory.mktemp("clip")
    scene = make_scene("hinge", num_frames=10, size=(128, 96), seed=3, noise=2.0)
    write_video(d / "frames", scene.frames, scene.fps)
    (d / "masks").mkdir()
    for i, m in enumerate(scene.masks):
        cv2.imwrite(str(d / "masks" / f"{i:05d}.png"), m.astype(np.uint8) * 255)
    target = np.zeros((64, 64, 4), np.uint8)
    target[16:48, 12:52] = (200, 80, 40, 255)
    target[20:30, 20:30, :3] = 250
    cv2.imwrite(str(d / "target.png"), cv2.cvtColor(target, cv2.COLOR_RGBA2BGRA))
    return d


def without_timings(metadata: str) -> dict:
    """A prior's metadata without its wall-clock timings, which are the only thing allowed to vary."""
    return {k: v for k, v in json.loads(metadata).items() if k != "timings"}


def test_extract_and_transfer_repeat_exactly_in_fresh_processes(clip, tmp_path):
    envs = {1: None, 2: ONE_THREAD}
    cli(*((["extract", clip / "frames", "--masks", clip / "masks", "--parts", "2", "-o", tmp_path / f"p{run}.npz"],
           env) for run, env in envs.items()))
    # both renders from the first prior, so a difference in them is the renderer's own
    cli(*((["transfer", tmp_path / "p1.npz", clip / "target.png", "-o", tmp_path / f"frames{run}"], env)
          for run, env in envs.items()))

    with np.load(tmp_path / "p1.npz") as a, np.load(tmp_path / "p2.npz") as b:
        assert a.files == b.files
        for key in a.files:
            if key == "metadata":
                assert without_timings(a[key].item()) == without_timings(b[key].item())
            else:
                assert a[key].dtype == b[key].dtype and a[key].tobytes() == b[key].tobytes(), key
        assert a["poses"].shape[1] == 10

    first, second = sorted((tmp_path / "frames1").iterdir()), sorted((tmp_path / "frames2").iterdir())
    assert [f.name for f in first] == [f.name for f in second] and len(first) == 10
    for f, g in zip(first, second):
        assert f.read_bytes() == g.read_bytes(), f.name
    assert first[0].read_bytes() != first[-1].read_bytes()  # the object does move


def test_extract_repeats_exactly_in_one_process(clip):
    """No state carried between calls (a shared RNG advanced by the first run would change the second)."""
    a, b = (pipeline.extract(clip / "frames", masks=clip / "masks", options=ExtractOptions(parts=2))
            for _ in range(2))
    for key in ("poses", "rotations", "translations", "centroids", "radii"):
        assert getattr(a, key).tobytes() == getattr(b, key).tobytes(), key
    assert a.extras.keys() == b.extras.keys()
    for key in a.extras:
        assert np.asarray(a.extras[key]).tobytes() == np.asarray(b.extras[key]).tobytes(), key


def test_render_does_not_depend_on_the_thread_count():
    """Parallel loops of the rasterizer give bitwise the same image on 1 thread as on all of them."""
    rng = np.random.default_rng(0)
    n = 3000
    g = Gaussians.from_rgb(rng.normal(size=(n, 3)) * [1, 1, 0.3] + [0, 0, 5], rng.uniform(size=(n, 3)),
                           rng.uniform(0.02, 0.2, size=n), rng.uniform(0.2, 0.99, size=n))
    cam = Camera.from_fov(96, 72)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        single = render(g, cam, (1.0, 1.0, 1.0))
    finally:
        numba.set_num_threads(threads)
    full = render(g, cam, (1.0, 1.0, 1.0))
    assert single.image.tobytes() == full.image.tobytes()
    assert single.image.std() > 0.05  # a real picture, not a blank one


def test_salient_model_does_not_depend_on_the_thread_count():
    from marionette.segment import SalientModel

    image = make_scene("inplane", num_frames=2, size=(160, 120), seed=1).frames[0]
    one, two = (SalientModel(threads=n).predict(image) for n in (1, 2))
    assert one.tobytes() == two.tobytes()


def test_grabcut_repeats_exactly_in_one_process():
    """A target masked by GrabCut must not depend on what ran before it (``run`` vs ``extract`` + ``transfer``)."""
    from marionette.segment import grabcut_mask

    image = make_scene("outofplane", num_frames=2, size=(160, 120), seed=4, noise=3.0).frames[0]
    first = grabcut_mask(image)
    for _ in range(3):
        assert np.array_equal(grabcut_mask(image), first)


def other_blas_kernel() -> str:
    """An OpenBLAS kernel other than the one this machine picks by itself.

    The kernel changes the last bits of every LAPACK/BLAS result. On x86-64, Sandybridge's has no fused
    multiply-add, so it rounds even a 3x3 matrix product otherwise than Haswell's, SkylakeX's or Zen's (which
    round small products alike); where it is the default kernel, Haswell is the other.
    """
    picked = {info.get("architecture") for info in threadpoolctl.threadpool_info() if info["user_api"] == "blas"}
    return "Sandybridge" if "Sandybridge" not in picked and platform.machine() in ("x86_64", "AMD64") else "Haswell"


#: The machine's own kernel on every thread, then another kernel on one thread.
KERNELS = [{}, {**ONE_THREAD, "OPENBLAS_CORETYPE": other_blas_kernel()}]


def rotation_gap_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (degrees) of R_aᵀ R_b for poses (..., 4, 4)."""
    rel = np.swapaxes(a[..., :3, :3], -1, -2) @ b[..., :3, :3]
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)))


@pytest.mark.parametrize("motion, frames, size, parts", [("outofplane", 16, (160, 120), "auto"),
                                                        ("hinge", 20, (200, 150), "auto"),
                                                        ("translation", 16, (160, 120), "1")])
def test_parts_auto_does_not_follow_the_blas_kernel_or_thread_count(motion, frames, size, parts, tmp_path):
    """Issue 14: the same ``extract --parts auto`` under 1 and 2 threads and other BLAS kernels.

    The part count (and how it was chosen) must agree everywhere; with ``--parts 1``, the choice of strict tracks
    too. The hinge's still body and lid agree within 0.15°: the lid's free poses do differ (PnP RANSAC keeps 5 or
    6 inliers on its few tracks, by the last bits), and the hinge fit of each used to settle in a minimum of its
    own, 46° apart on this clip; fitted from two starts, both reach the best one, near the truth. A one-part
    motion's tracks' poses agree within 0.05°; the joint fit, thousands of descent steps on them, carries the
    kernels' last bits to 0.08-0.18° (the outofplane clip, on two CPUs: the machine's kernel against
    Sandybridge's, which has no fused multiply-add), far below its own error there (4.5° at the end): held to
    0.25°.
    """
    scene = make_scene(motion, seed=0, num_frames=frames, size=size)
    write_video(tmp_path / "frames", scene.frames, scene.fps)
    (tmp_path / "masks").mkdir()
    for i, m in enumerate(scene.masks):
        cv2.imwrite(str(tmp_path / "masks" / f"{i:05d}.png"), m.astype(np.uint8) * 255)
    outs = [tmp_path / f"prior{run}.npz" for run in range(len(KERNELS))]
    cli(*((["extract", tmp_path / "frames", "--masks", tmp_path / "masks", "--parts", parts, "-o", out], env)
          for out, env in zip(outs, KERNELS)))
    priors = []
    for out in outs:
        with np.load(out) as f:
            priors.append((f["poses"], json.loads(f["metadata"].item())))
    poses, meta = priors[0]
    truth = 2 if motion == "hinge" else 1
    assert meta["num_parts"] == truth
    for other, other_meta in priors[1:]:
        assert other_meta["num_parts"] == meta["num_parts"]
        assert other_meta.get("part_selection_note") == meta.get("part_selection_note")
        assert other_meta["tracks"] == meta["tracks"]
        if motion == "hinge":  # parts in the order of how far they turn: the still body, then the lid
            order = np.argsort(rotation_gap_deg(np.eye(4), poses[:, -1]))
            other_order = np.argsort(rotation_gap_deg(np.eye(4), other[:, -1]))
            assert rotation_gap_deg(poses[order], other[other_order]).max() < 0.15
        else:
            assert rotation_gap_deg(poses, other).max() < 0.25
    if motion == "hinge":  # and the lid they agree on is the true one (its free poses alone: 17° off)
        lid = int(np.argmax(rotation_gap_deg(np.eye(4), poses[:, -1])))
        assert np.median(rotation_gap_deg(poses[lid, 1:], scene.poses[1, 1:])) < 5.0

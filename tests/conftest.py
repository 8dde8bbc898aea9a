"""Fixtures shared by the tests: the xdist workers' set-up (one BLAS thread each, the numba compiling shared on a
cold cache); a small prior file and a target image."""

import contextlib
import fcntl
import functools
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
import threadpoolctl

from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.io import write_prior
from marionette.prior import SpatPrior


def _small_view():
    """A camera and 200 Gaussians of SH degree 3 in front of it (float32, as every caller's Gaussians)."""
    from marionette.camera import Camera
    from marionette.gaussians import Gaussians

    rng = np.random.default_rng(0)
    n = 200
    gaussians = Gaussians.from_rgb(rng.normal(size=(n, 3)) * 0.3 + [0, 0, 3], rng.uniform(size=(n, 3)),
                                   rng.uniform(0.02, 0.1, size=n), rng.uniform(0.3, 0.9, size=n))
    gaussians = gaussians.with_sh(np.concatenate([gaussians.sh, rng.normal(size=(n, 15, 3)) * 0.05], axis=1))
    return gaussians.turned(np.array([[0.9, 0.1, 0.3, 0.0]])), Camera.from_fov(48, 36)


def _compile_forward() -> None:
    """The rasterizer's forward kernels (SH colours and turns included; ``render`` runs the same ones)."""
    from marionette.render.backward import render_with_grad

    render_with_grad(*_small_view())


def _compile_backward() -> None:
    """The rasterizer's backward kernels, pose gradients included."""
    from marionette.render.backward import render_with_grad

    gaussians, camera = _small_view()
    view = render_with_grad(gaussians, camera)
    view.backward(np.ones((camera.height, camera.width, 3), np.float32), np.ones((camera.height, camera.width)),
                  groups=[np.arange(100), np.arange(100, 200)])


def _compile_extraction() -> None:
    """The tracker's and the part fits' kernels, the synthetic renderer's and the target lift's: a tiny hinge's
    prior, then a lifted photo."""
    from marionette.source import ExtractOptions, extract_prior
    from marionette.synthetic import make_scene
    from marionette.target.lift import lift_image

    scene = make_scene("hinge", num_frames=8, size=(96, 72), seed=1)
    extract_prior(scene.frames, scene.masks, scene.camera.K, fps=24.0, options=ExtractOptions(parts="auto"))
    lift_image(scene.frames[0], mask=scene.masks[0])


@contextlib.contextmanager
def _held(lock: Path, mode: int) -> Iterator[None]:
    with open(lock, "a") as f:
        fcntl.flock(f, mode)
        yield


def _head_start(compile_kernels: Callable[[], None]) -> None:
    try:
        compile_kernels()
    except Exception:  # only a head start: a test that needs the same code shows what went wrong
        pass


def _share_the_compiling(worker: int, shared: Path) -> None:
    """On a cold numba cache (a fresh clone) every worker would compile every kernel (~30 s of it each).

    Even workers compile the rasterizer, forward then backward (~16 s); odd ones the extraction's kernels
    (~14 s), each under its share's lock, then wait for the others' locks so that the kernels they did
    not compile are read from the cache. The backward pass, which few tests use, is not waited for: an odd worker
    starts its tests once the forward kernels are in the cache, and its first backward pass waits for them
    (:func:`_backward_waits_for`). A warm cache makes all this a second's work."""
    forward, backward, extraction = (shared / f"compile-{name}.lock" for name in ("forward", "backward", "extraction"))
    if worker % 2 == 0:
        with _held(backward, fcntl.LOCK_EX):
            with _held(forward, fcntl.LOCK_EX):
                _head_start(_compile_forward)
            _head_start(_compile_backward)
        with _held(extraction, fcntl.LOCK_SH):  # until the extraction's kernels are in the cache
            pass
        return
    with _held(extraction, fcntl.LOCK_EX):
        _head_start(_compile_extraction)
    with _held(forward, fcntl.LOCK_SH):
        _backward_waits_for(backward)


def _backward_waits_for(lock: Path) -> None:
    """Make this process's first backward pass wait for ``lock`` (held while another worker compiles it)."""
    from marionette.render.backward import RenderWithGrad

    first = RenderWithGrad.backward

    @functools.wraps(first)
    def backward_once_compiled(self, *args, **kwargs):
        with _held(lock, fcntl.LOCK_SH):
            RenderWithGrad.backward = first
        return first(self, *args, **kwargs)

    RenderWithGrad.backward = backward_once_compiled


def pytest_collection_modifyitems(items):
    """Modules marked ``heavy`` first, the others in their order: the workers take whole files in this order,
    and a long file taken last would run alone while the other cores wait."""
    items.sort(key=lambda item: item.get_closest_marker("heavy") is None)


@pytest.fixture(scope="session", autouse=True)
def xdist_worker(request, tmp_path_factory):
    """One BLAS thread per xdist worker, then the compiling shared (:func:`_share_the_compiling`).

    pytest-xdist runs one worker per core, so a worker's BLAS threads could only wait on the other workers
    (OpenBLAS's waiting threads spin: on two cores that made the suite 15 % slower). Set once the test modules,
    and with them every BLAS library, are loaded; subprocesses keep the machine's own setting."""
    worker = getattr(request.config, "workerinput", None)
    if worker is None:
        yield
        return
    with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
        # The workers' temporary folders share this parent.
        _share_the_compiling(int(worker["workerid"].removeprefix("gw")), tmp_path_factory.getbasetemp().parent)
        yield


@pytest.fixture
def prior_file(tmp_path):
    t = 8
    c = np.array([0, 0, 4.0])
    poses = [make_transform(axis_angle_to_matrix([0, 0, 0.1 * i]), [0, 0, 0]) for i in range(t)]
    poses = np.array([make_transform(np.eye(3), c) @ p @ make_transform(np.eye(3), -c) for p in poses])[None]
    prior = SpatPrior.from_poses(poses, np.tile(c, (1, t, 1)), np.ones(1), fps=12.0, image_size=(64, 48),
                                 intrinsics=np.eye(3))
    path = tmp_path / "prior.npz"
    write_prior(path, prior)
    return path


@pytest.fixture
def target_png(tmp_path):
    img = np.zeros((64, 64, 4), np.uint8)
    cv2.rectangle(img, (16, 20), (48, 44), (30, 120, 230, 255), -1)
    cv2.circle(img, (32, 32), 6, (250, 250, 20, 255), -1)
    path = tmp_path / "target.png"
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA))
    return path

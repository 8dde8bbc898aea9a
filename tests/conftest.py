"""Fixtures shared by the tests: the xdist workers' set-up (one BLAS thread each, the numba compiling shared on a
cold cache); a small prior file and a target image."""

import fcntl
from pathlib import Path

import cv2
import numpy as np
import pytest
import threadpoolctl

from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.io import write_prior
from marionette.prior import SpatPrior


def _compile_rendering() -> None:
    """The rasterizer's forward and backward kernels: two fitting steps on a tiny scene."""
    from marionette.reconstruct import ReconstructOptions, reconstruct_object
    from marionette.synthetic import make_scene

    scene = make_scene("outofplane", num_frames=2, size=(48, 36))
    reconstruct_object(scene.frames, scene.masks, scene.ground_truth_prior(), options=ReconstructOptions(iterations=2))


def _compile_extraction() -> None:
    """The tracker's and the part fits' kernels, and the target lift's: a tiny hinge's prior, then a lifted photo."""
    from marionette.source import ExtractOptions, extract_prior
    from marionette.synthetic import make_scene
    from marionette.target.lift import lift_image

    scene = make_scene("hinge", num_frames=8, size=(96, 72), seed=1)
    extract_prior(scene.frames, scene.masks, scene.camera.K, fps=24.0, options=ExtractOptions(parts="auto"))
    lift_image(scene.frames[0], mask=scene.masks[0])


def _share_the_compiling(worker: int, shared: Path) -> None:
    """On a cold numba cache (a fresh clone) every worker would compile every kernel, ~80 s each on two cores.
    Worker 2k compiles the rendering kernels and 2k+1 the extraction's, each under its share's lock; then each
    waits for the other share's lock, so that the kernels it did not compile are read from the cache. A warm
    cache makes this a second's work."""
    shares = [_compile_rendering, _compile_extraction]
    locks = [shared / f"compile-{i}.lock" for i in range(len(shares))]
    mine = worker % len(shares)
    with open(locks[mine], "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        try:
            shares[mine]()
        except Exception:  # only a head start: a test that needs the same code shows what went wrong
            pass
    for i, lock in enumerate(locks):
        if i != mine:
            with open(lock, "a") as other:
                fcntl.flock(other, fcntl.LOCK_SH)


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

"""Fixtures shared by the tests: one BLAS thread per xdist worker; a small prior file and a target image."""

import os

import cv2
import numpy as np
import pytest
import threadpoolctl

from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.io import write_prior
from marionette.prior import SpatPrior


@pytest.fixture(scope="session", autouse=True)
def one_thread_per_worker():
    """pytest-xdist runs one worker per core, so a worker's BLAS threads could only wait on the other workers
    (OpenBLAS's waiting threads spin: on two cores that made the suite 15 % slower). Set once the test modules,
    and with them every BLAS library, are loaded; subprocesses keep the machine's own setting."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
        return
    with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
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

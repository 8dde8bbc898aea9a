"""The prior plot: a complete PNG of the expected size, written atomically."""

import subprocess
import sys

import cv2
import numpy as np
import pytest
from matplotlib.figure import Figure

from marionette.errors import InputError
from marionette.plot import DPI, FIGURE_SIZE, plot_prior
from marionette.synthetic import make_scene

WIDTH, HEIGHT = int(FIGURE_SIZE[0] * DPI), int(FIGURE_SIZE[1] * DPI)
#: matplotlib's first two cycle colours, C0 and C1, as BGR.
BLUE, ORANGE = (180, 119, 31), (14, 127, 255)


@pytest.fixture(scope="module")
def hinge_prior():
    return make_scene("hinge", num_frames=16, size=(64, 48), seed=1).ground_truth_prior()


def _count(image, bgr):
    return int(np.all(np.abs(image.astype(int) - bgr) <= 2, axis=-1).sum())


def test_writes_png_of_expected_size(tmp_path):
    prior = make_scene("oscillation", num_frames=16, size=(64, 48), seed=0).ground_truth_prior()
    path = tmp_path / "osc.png"
    plot_prior(prior, path, title="oscillation")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = cv2.imread(str(path))
    assert image.shape == (HEIGHT, WIDTH, 3)
    assert _count(image, BLUE) > 500  # the one part's lines are drawn
    assert _count(image, ORANGE) == 0


def test_two_parts_two_colours(tmp_path, hinge_prior):
    path = tmp_path / "hinge.png"
    plot_prior(hinge_prior, path)
    image = cv2.imread(str(path))
    assert _count(image, BLUE) > 500 and _count(image, ORANGE) > 500


def test_existing_file_replaced_only_by_complete_one(tmp_path, hinge_prior, monkeypatch):
    path = tmp_path / "plot.png"
    path.write_bytes(b"old")

    def failing_savefig(self, fname, **kwargs):
        with open(fname, "wb") as f:
            f.write(b"\x89PNG partial")
        raise RuntimeError("disk full")

    with monkeypatch.context() as m:
        m.setattr(Figure, "savefig", failing_savefig)
        with pytest.raises(RuntimeError, match="disk full"):
            plot_prior(hinge_prior, path)
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["plot.png"]  # no temporary file left
    plot_prior(hinge_prior, path)
    assert cv2.imread(str(path)).shape == (HEIGHT, WIDTH, 3)


@pytest.mark.parametrize("name, message", [
    ("missing/plot.png", "does not exist"),
    ("plot.jpg", ".png"),
    ("folder.png", "is a folder"),
])
def test_bad_path(tmp_path, hinge_prior, name, message):
    (tmp_path / "folder.png").mkdir()
    with pytest.raises(InputError, match=message):
        plot_prior(hinge_prior, tmp_path / name)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.png"]


def test_leaves_no_pyplot_state(tmp_path):
    # In a fresh interpreter, so other tests' imports cannot hide a pyplot import.
    code = (
        "import sys, numpy as np\n"
        "from marionette.prior import SpatPrior\n"
        "from marionette.plot import plot_prior\n"
        "p = SpatPrior.identity(3, fps=10.0, image_size=(8, 8), intrinsics=np.eye(3), centroid=[0, 0, 1], radius=1)\n"
        f"plot_prior(p, {str(tmp_path / 'id.png')!r})\n"
        "assert 'matplotlib.pyplot' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    assert (tmp_path / "id.png").is_file()

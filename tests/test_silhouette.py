"""The rendered silhouette against the true masks: IoU and stray pixels, against a slow twin."""

import numpy as np
import pytest

from marionette.errors import InputError
from marionette.eval import SilhouetteReport, silhouette_frame
from marionette.eval.silhouette import STRAY_SHARE


def disc(h: int, w: int, cx: float, cy: float, r: float) -> np.ndarray:
    y, x = np.mgrid[:h, :w]
    return (x - cx) ** 2 + (y - cy) ** 2 <= r * r


def _stray_share(alpha, mask, reach, drawn):
    """Slow twin: each drawn pixel's distance to every mask pixel, by brute force."""
    ys, xs = np.nonzero(mask)
    stray = 0
    for y, x in zip(*np.nonzero(alpha >= drawn)):
        if len(ys) == 0 or np.sqrt(((ys - y) ** 2 + (xs - x) ** 2).min()) > reach:
            stray += 1
    return stray / mask.size


def test_a_render_on_its_mask_agrees_whole_and_draws_nothing_stray():
    mask = disc(60, 80, 40, 30, 12)
    assert silhouette_frame(mask.astype(np.float32), mask) == (1.0, 0.0)


def test_a_shifted_render_loses_overlap_but_stays_within_reach():
    mask = disc(60, 80, 40, 30, 12)
    alpha = disc(60, 80, 45, 30, 12).astype(np.float32)
    iou, stray = silhouette_frame(alpha, mask)
    assert iou == pytest.approx((mask & (alpha > 0)).sum() / (mask | (alpha > 0)).sum())
    assert 0.4 < iou < 0.8 and stray == 0.0


def test_a_faint_floater_far_from_the_mask_is_stray_but_not_silhouette():
    mask = disc(60, 80, 20, 30, 8)
    alpha = mask.astype(np.float32)
    alpha[5:15, 60:70] = 0.3  # 100 pixels, 40 px from the object
    iou, stray = silhouette_frame(alpha, mask)
    assert iou == 1.0 and stray == pytest.approx(100 / mask.size)


@pytest.mark.parametrize("seed", range(4))
def test_stray_share_matches_the_brute_force_twin(seed):
    rng = np.random.default_rng(seed)
    mask = disc(24, 32, *rng.uniform(8, 20, 2), rng.uniform(2, 6))
    alpha = rng.random((24, 32)).astype(np.float32) * (rng.random((24, 32)) < 0.3)
    reach = float(rng.uniform(2, 8))
    assert silhouette_frame(alpha, mask, reach=reach)[1] == pytest.approx(
        _stray_share(alpha, mask, reach, 0.1), abs=1e-12)


def test_an_empty_mask_makes_every_drawn_pixel_stray():
    empty = np.zeros((10, 10), bool)
    alpha = np.zeros((10, 10), np.float32)
    assert silhouette_frame(alpha, empty) == (1.0, 0.0)
    alpha[2, 3] = 0.9
    assert silhouette_frame(alpha, empty) == (0.0, 0.01)


def test_the_report_lists_frames_with_more_than_the_stray_share():
    mask = disc(60, 80, 20, 30, 8)
    clean = mask.astype(np.float32)
    floater = clean.copy()
    floater[:10, 60:] = 1.0  # 200 pixels: 4 % of the frame
    report = SilhouetteReport.of([clean, floater, clean], [mask, mask, mask])
    assert report.stray_frames.tolist() == [1] and report.stray_share[1] > STRAY_SHARE
    summary = report.summary()
    assert summary["stray_frames"] == [1] and summary["iou_median"] == 1.0
    assert summary["worst_frame"] == 1 and summary["iou_worst"] < 1.0
    assert summary["iou_per_frame"] == [1.0, summary["iou_worst"], 1.0]


def test_alpha_and_mask_of_different_sizes_are_refused():
    with pytest.raises(InputError, match="one size"):
        silhouette_frame(np.zeros((4, 5)), np.zeros((5, 4), bool))

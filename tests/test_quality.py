"""Which frames a fit placed: their silhouette matches the mask, or holds what something in front leaves of it."""

import numpy as np

from marionette.reconstruct.quality import placed_frames


def disc(centre_x: float, radius: float, size=(120, 200)) -> np.ndarray:
    """(H, W) bool disc at (centre_x, 60)."""
    y, x = np.mgrid[:size[0], :size[1]]
    return (x - centre_x) ** 2 + (y - 60) ** 2 <= radius ** 2


def rolling_ball(num_frames: int = 9) -> tuple[list[np.ndarray], np.ndarray]:
    """A ball rolling right behind a trunk (columns 80-100) that hides part of frames 3-5: truth and masks."""
    truth = [disc(40 + 10 * t, 25) for t in range(num_frames)]
    masks = np.array(truth)
    masks[3:6, :, 80:100] = False
    return truth, masks


def test_a_ball_drawn_whole_where_its_visible_rest_is_is_placed():
    truth, masks = rolling_ball()
    notes = placed_frames(lambda t: truth[t], masks, [1, 3, 4, 5])
    assert set(notes) == {1, 3, 4, 5}
    assert notes[1].startswith("silhouette IoU 1.00")
    assert "behind something in front" in notes[4] and "frames 2 and 6" in notes[4]


def test_a_ball_drawn_beside_or_too_big_or_where_nothing_shows_is_not():
    truth, masks = rolling_ball()
    shifted = {4: disc(80 + 8, 25)}  # 8 px off: the mask's right sliver is outside
    assert 4 not in placed_frames(lambda t: shifted.get(t, truth[t]), masks, [4])
    near = {4: disc(80, 34)}  # covers what shows, at nearly twice the area of its neighbours
    assert 4 not in placed_frames(lambda t: near.get(t, truth[t]), masks, [4])
    hidden = masks.copy()
    hidden[4] = False
    assert 4 not in placed_frames(lambda t: truth[t], hidden, [4])
    # Placed frames on either side are what it is compared with: with none, nothing behind the trunk is placed.
    assert placed_frames(lambda t: truth[t], masks, [4]) and not placed_frames(
        lambda t: truth[t] if t == 4 else np.zeros_like(truth[t]), masks, [4])

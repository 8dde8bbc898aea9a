"""Gaussians that land off the object's mask in many frames are strays; a frame or two off is not enough."""

import numpy as np

from marionette.reconstruct.strays import STRAY_FRAMES, stray_gaussians


def test_a_centre_off_the_mask_in_many_frames_is_a_stray_and_one_off_in_few_is_not():
    K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
    rng = np.random.default_rng(0)
    body = rng.uniform(-0.3, 0.3, (50, 3)) * [1, 1, 0]  # a flat square facing the camera, 60 px across at z=1
    floater = np.array([[0.6, 0.0, 0.0]])  # 30 px beside it in every frame
    means = np.concatenate([body, floater, [[0.28, 0.0, 0.0]]])
    parts = np.zeros(len(means), int)
    poses, masks = {}, np.zeros((8, 120, 160), bool)
    for t in range(8):
        pose = np.eye(4)[None].copy()
        pose[0, :3, 3] = [0.02 * t, 0.0, 1.0]
        poses[t] = pose
        x0 = int(round(80 + 2 * t - 30))
        masks[t, 30:90, x0:x0 + 60] = True
    masks[3, 30:90, 80 + 6:] = False  # frame 3's mask misses the right half: the last Gaussian is off it there
    strays = stray_gaussians(means, parts, poses, masks, K)
    assert strays.tolist() == [False] * 50 + [True, False]
    assert 1 / 8 < STRAY_FRAMES  # one frame in eight is allowed


def test_frames_with_empty_masks_or_points_out_of_view_do_not_count():
    K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
    means = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])  # the second projects out of the image
    pose = np.eye(4)[None].copy()
    pose[0, 2, 3] = 1.0
    masks = np.zeros((2, 120, 160), bool)
    masks[0, 50:70, 70:90] = True
    assert stray_gaussians(means, np.zeros(2, int), {0: pose, 1: pose}, masks, K).tolist() == [False, False]

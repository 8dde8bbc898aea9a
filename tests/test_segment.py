import socket

import cv2
import numpy as np
import onnxruntime
import pytest

from marionette.errors import InputError
from marionette.segment import SalientModel, grabcut_mask, refine_with_grabcut, salient_mask
from marionette.segment._grabcut import keep_main_object
from marionette.segment._u2net import MODEL_PATH, default_model


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


def scene(H=240, W=320, seed=0):
    """A textured, saturated object (a rounded box with a handle) on a gently graded background.

    Returns the (H, W, 3) uint8 RGB image and its (H, W) bool true mask.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:H, :W].astype(np.float32)
    bg = np.dstack([205 + 25 * yy / H, 210 + 20 * yy / H, 220 + 15 * xx / W])
    body = ((xx - 0.6 * W) / (0.22 * W)) ** 4 + ((yy - 0.55 * H) / (0.3 * H)) ** 4 < 1
    handle = (np.abs(yy - 0.4 * H) < 0.05 * H) & (xx > 0.2 * W) & (xx < 0.5 * W)
    inside = body | handle
    hue = ((xx + yy) // 12 % 6).astype(np.uint8) * 30
    value = (170 + 60 * ((xx // 16 + yy // 16) % 2)).astype(np.uint8)
    obj = cv2.cvtColor(np.dstack([hue, np.full_like(hue, 230), value]), cv2.COLOR_HSV2RGB)
    img = np.where(inside[..., None], obj, bg) + rng.normal(0, 2, (H, W, 3))
    return np.clip(img, 0, 255).astype(np.uint8), inside


@pytest.fixture(scope="module")
def model():
    return SalientModel()


def test_model_ships_with_the_package_and_loads_offline(monkeypatch):
    assert MODEL_PATH.is_file() and MODEL_PATH.stat().st_size == 4574861
    assert (MODEL_PATH.parent / "LICENSE-u2netp.txt").is_file()

    def no_network(*args, **kwargs):
        raise AssertionError("segmentation tried to use the network")

    monkeypatch.setattr(socket.socket, "connect", no_network)
    prob = SalientModel().predict(scene()[0])
    assert prob.max() > 0.5


def test_predict_shape_dtype_and_range(model):
    img, _ = scene(H=90, W=130)
    prob = model.predict(img)
    assert prob.shape == (90, 130) and prob.dtype == np.float32
    # Min-max normalised, then bilinearly resized: the range stays [0, 1] and is nearly spanned.
    assert prob.min() >= 0 and prob.max() <= 1 and prob.min() < 0.01 and prob.max() > 0.99
    raw = model.predict(img, normalize=False)
    assert raw.shape == (90, 130) and raw.dtype == np.float32 and 0 <= raw.min() <= raw.max() <= 1


def test_salient_mask_finds_the_synthetic_object(model):
    for seed in range(2):
        img, truth = scene(seed=seed)
        mask = salient_mask(img, model=model)
        assert mask.dtype == bool and mask.shape == truth.shape
        # Measured IoU 0.99 (an easy, high-contrast scene); 0.8 leaves room for other runtimes.
        assert iou(mask, truth) > 0.8


def test_grabcut_from_the_default_box_finds_the_synthetic_object():
    img, truth = scene()
    # Measured IoU 1.0: the object's colours share nothing with the background.
    assert iou(grabcut_mask(img), truth) > 0.9


def test_grabcut_snaps_a_loose_prior_to_the_object():
    img, truth = scene()
    loose = cv2.dilate(truth.astype(np.uint8), np.ones((9, 9), np.uint8))
    prior = cv2.GaussianBlur(loose.astype(np.float32), (0, 0), 3)  # soft edge ~6 px too far out
    before = iou(prior >= 0.5, truth)
    after = iou(refine_with_grabcut(img, prior), truth)
    assert after > 0.9 and after > before


def test_blank_images_have_no_object(model):
    for value in (0, 128, 255):
        blank = np.full((60, 80, 3), value, np.uint8)
        with pytest.raises(InputError, match="no salient object"):
            salient_mask(blank, model=model)
        # Both GrabCut colour models fit the one colour equally well: nothing is foreground.
        with pytest.raises(InputError, match="no object"):
            grabcut_mask(blank)


def test_model_is_loaded_once(monkeypatch):
    created = []
    session_class = onnxruntime.InferenceSession

    def counting(*args, **kwargs):
        created.append(1)
        return session_class(*args, **kwargs)

    monkeypatch.setattr(onnxruntime, "InferenceSession", counting)
    img, _ = scene(H=64, W=64)
    model = SalientModel()
    assert not created  # lazy: nothing loaded before the first prediction
    model.predict(img)
    model.predict(img, normalize=False)
    salient_mask(img, model=model)
    assert len(created) == 1
    assert default_model() is default_model()


def test_release_frees_the_session_and_the_next_prediction_is_the_same():
    img, _ = scene(H=64, W=64)
    model = SalientModel()
    first = model.predict(img)
    held = model._session
    model.release()
    assert model._session is None
    np.testing.assert_array_equal(model.predict(img), first)
    assert model._session is not None and model._session is not held


def test_the_default_model_holds_no_session_after_one_image_or_a_video(monkeypatch):
    """Its memory arena (0.3-0.5 GB) would otherwise stay for the rest of the process; a model passed in is the
    caller's to keep."""
    from marionette.segment import Prompt, prompted_mask
    from marionette.source.foreground import auto_masks

    shared = SalientModel()
    monkeypatch.setattr("marionette.segment._u2net.default_model", lambda: shared)
    img, _ = scene(H=64, W=64)
    salient_mask(img)
    assert shared._session is None
    prompted_mask(img, Prompt(points=((32.0, 32.0),)))
    assert shared._session is None
    frames = np.stack([np.roll(img, 2 * t, axis=1) for t in range(4)])
    auto_masks(frames)
    assert shared._session is None
    mine = SalientModel()
    salient_mask(img, model=mine)
    auto_masks(frames, model=mine)
    assert mine._session is not None


def test_bad_inputs_are_refused(model):
    img, truth = scene(H=64, W=64)
    for bad in (img[..., 0], img.astype(np.float32), np.dstack([img, img[..., :1]])):
        with pytest.raises(InputError, match="image must be"):
            model.predict(bad)
        with pytest.raises(InputError, match="image must be"):
            grabcut_mask(bad)
    with pytest.raises(InputError, match="threshold"):
        salient_mask(img, threshold=1.5, model=model)
    with pytest.raises(InputError, match="rect"):
        grabcut_mask(img, rect=(0, 0, 64, 64))
    with pytest.raises(InputError, match="rect"):
        grabcut_mask(img, rect=(10, 10, 60, 20))
    with pytest.raises(InputError, match="not both"):
        grabcut_mask(img, rect=(5, 5, 20, 20), prior=truth.astype(float))
    with pytest.raises(InputError, match="prior must be"):
        grabcut_mask(img, prior=np.zeros((10, 10)))
    with pytest.raises(InputError, match="no pixel >= 0.5"):
        grabcut_mask(img, prior=np.zeros((64, 64)))


def test_keep_main_object_drops_specks_and_fills_only_small_holes():
    mask = np.zeros((200, 200), bool)
    mask[10:160, 10:160] = True  # main object, 21 684 px once holed
    mask[30:34, 30:34] = False  # 16 px hole (< 0.3 %): speckle, filled
    mask[50:90, 100:120] = False  # 800 px hole: real, kept
    mask[120:190, 165:195] = True  # 2100 px, < 20 % of the main object: dropped
    mask[164:198, 10:160] = True  # 5100 px >= 20 %: kept
    out = keep_main_object(mask)
    assert out[30:34, 30:34].all() and not out[50:90, 100:120].any()
    assert out[164:198, 10:160].all() and not out[120:190, 165:195].any()
    with pytest.raises(InputError, match="empty"):
        keep_main_object(np.zeros((10, 10), bool))

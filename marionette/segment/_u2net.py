"""Salient-object masks from U²-Netp, run offline with ONNX Runtime.

U²-Net (Qin, Zhang, Huang, Dehghan, Zaiane and Jagersand, "U²-Net: Going
Deeper with Nested U-Structure for Salient Object Detection", Pattern
Recognition 106, 107404, 2020, doi:10.1016/j.patcog.2020.107404) predicts,
for every pixel, the probability that it belongs to the most eye-catching
object. Its 4.6 MB variant U²-Netp ships inside the package
(``models/u2netp.onnx``, Apache-2.0, see ``models/LICENSE-u2netp.txt``), so
no network is needed at run time.

Images are RGB ``uint8`` of shape (H, W, 3).
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ._grabcut import check_image, keep_main_object

__all__ = ["MODEL_PATH", "SalientModel", "default_model", "model_in_use", "predict_raw", "salient_mask"]

MODEL_PATH = Path(__file__).parent / "models" / "u2netp.onnx"

# The network's training resolution and ImageNet statistics (reference U²-Net
# inference code, data_loader.py :: ToTensorLab).
_SIZE = 320
_MEAN = np.array([0.485, 0.456, 0.406], np.float32)
_STD = np.array([0.229, 0.224, 0.225], np.float32)


class SalientModel:
    """U²-Netp saliency predictor; the ONNX session is created on first use.

    Parameters
    ----------
    path : path of the ``.onnx`` file, the packaged U²-Netp by default.
    threads : int, optional
        ONNX Runtime intra-op threads; default: the cores this process may use.
    """

    def __init__(self, path: str | Path = MODEL_PATH, *, threads: int | None = None):
        self.path = Path(path)
        # The cores this process may run on (a container's share), where the OS can tell.
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        self.threads = threads or cores or 1
        self._session = None

    def _run(self, x: np.ndarray) -> np.ndarray:
        """(1, 3, 320, 320) float32 network input → (320, 320) float32 fused map d1."""
        session = self._session  # held here: another thread may release it meanwhile
        if session is None:
            # Imported here: onnxruntime costs ~0.2 s to import, paid only when a mask is needed.
            import onnxruntime as ort

            if not self.path.is_file():
                raise InputError(f"salient-object model not found: {self.path}")
            options = ort.SessionOptions()
            options.intra_op_num_threads = self.threads
            options.inter_op_num_threads = 1
            session = self._session = ort.InferenceSession(str(self.path), options,
                                                           providers=["CPUExecutionProvider"])
        inputs = session.get_inputs()
        # The first output is the fused map d1 (the others are side outputs d2…d7),
        # already passed through a sigmoid inside the exported graph.
        d1 = session.run([session.get_outputs()[0].name], {inputs[0].name: x})[0]
        return d1[0, 0]

    def release(self) -> None:
        """Free the ONNX session. Its memory arena keeps what the largest run needed (about 0.3 GB after one
        prediction, 0.5 GB after a few) for as long as the session lives; the next prediction creates a new
        session (about 40 ms)."""
        self._session = None

    def predict(self, image: np.ndarray, *, normalize: bool = True) -> np.ndarray:
        """(H, W, 3) uint8 RGB image → (H, W) float32 saliency map in [0, 1].

        Preprocessing follows the reference code: resize to 320 x 320, divide
        by the image's maximum, subtract the ImageNet mean and divide by its
        standard deviation, NCHW float32. The d1 map is min-max normalised
        (``normalize=True``, as the reference does) and resized back to H x W
        bilinearly. With ``normalize=False`` the raw sigmoid probabilities
        are returned, whose peak tells whether there is an object at all.
        """
        check_image(image)
        H, W = image.shape[:2]
        # INTER_AREA averages when shrinking, like the reference's anti-aliased resize.
        small = cv2.resize(image, (_SIZE, _SIZE), interpolation=cv2.INTER_AREA).astype(np.float32)
        small /= max(float(small.max()), 1.0)  # an all-black image stays black
        x = ((small - _MEAN) / _STD).transpose(2, 0, 1)[None].astype(np.float32)
        prob = self._run(np.ascontiguousarray(x))
        if normalize:
            lo, hi = float(prob.min()), float(prob.max())
            prob = (prob - lo) / (hi - lo) if hi > lo else np.zeros_like(prob)
        prob = cv2.resize(prob, (W, H), interpolation=cv2.INTER_LINEAR)
        return np.clip(prob, 0.0, 1.0)


@functools.cache
def default_model() -> SalientModel:
    """The packaged U²-Netp, one object per process; its session is created when a batch of images needs it
    and released after (:func:`model_in_use`)."""
    return SalientModel()


@contextlib.contextmanager
def model_in_use(model: SalientModel | None) -> Iterator[SalientModel]:
    """``model``, or the default model, whose session is released on leaving (its memory arena is not worth
    keeping once a batch of images is done); a model passed in is the caller's to keep."""
    if model is not None:
        yield model
        return
    model = default_model()
    try:
        yield model
    finally:
        model.release()


def predict_raw(image: np.ndarray, model: SalientModel | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB image → (H, W) float32 raw probabilities of ``model`` (by default the packaged one,
    released after)."""
    with model_in_use(model) as used:
        return used.predict(image, normalize=False)


def salient_mask(image: np.ndarray, *, threshold: float = 0.5, keep_fraction: float = 0.2,
                 model: SalientModel | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB image → (H, W) bool mask of its salient object.

    Pixels whose U²-Netp probability (raw sigmoid, not min-max stretched, so
    that a featureless image stays empty) reaches ``threshold`` are kept;
    then the largest connected component, any other component of at least
    ``keep_fraction`` of its area, and small holes filled (see
    :func:`keep_main_object`).

    Raises
    ------
    InputError
        If no pixel reaches ``threshold`` (a blank or featureless image).
    """
    if not 0.0 < threshold < 1.0:
        raise InputError(f"threshold must lie in (0, 1), got {threshold}")
    prob = predict_raw(image, model)
    mask = prob >= threshold
    if not mask.any():
        raise InputError(f"no salient object found in the image (peak object probability "
                         f"{prob.max():.2f} < threshold {threshold})")
    return keep_main_object(mask, keep_fraction=keep_fraction)

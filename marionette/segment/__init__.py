"""Automatic object masks (Motion Marionette stages 2 and 4), offline on the CPU.

- :func:`salient_mask`: the packaged U²-Netp salient-object network (Qin et
  al., Pattern Recognition 2020) thresholded and cleaned up;
- :func:`grabcut_mask`: OpenCV GrabCut from a box or a probability map, a
  model-free fallback;
- :func:`refine_with_grabcut`: a saliency map's boundary snapped to colour
  edges by GrabCut;
- :class:`SalientModel`: the network itself, ``predict`` → (H, W) probabilities;
- :func:`prompted_mask`: the object a user clicked or boxed (:class:`Prompt`).

Images are RGB ``uint8`` (H, W, 3); masks are (H, W) bool.
"""

from ._grabcut import grabcut_mask, refine_with_grabcut
from ._u2net import SalientModel, salient_mask
from .prompt import Prompt, prompted_mask

__all__ = ["SalientModel", "salient_mask", "grabcut_mask", "refine_with_grabcut", "Prompt", "prompted_mask"]

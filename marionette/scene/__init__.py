"""The result inside the photo's own scene (``--background scene``).

:func:`clean_plate` removes the object from the photo (the region it
vacates, inpainted); :class:`SceneCompositor` renders the moving object over
that plate, seen as a plane at the object's depth, and carries the photo's
own detail on the object (:mod:`.composite`).
"""

from .composite import SceneCompositor
from .plate import clean_plate

__all__ = ["SceneCompositor", "clean_plate"]

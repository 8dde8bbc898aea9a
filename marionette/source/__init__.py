"""Source video → SpaT prior: 2D tracks, rigid poses, the prior (Motion Marionette stages 1-3)."""

from .extract import ExtractOptions, extract_prior
from .tracks import Tracks, track

__all__ = ["track", "Tracks", "extract_prior", "ExtractOptions"]

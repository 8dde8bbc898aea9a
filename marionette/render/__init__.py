"""Rendering: the CPU Gaussian rasterizer and spherical-harmonic colours."""

from .rasterizer import RenderOutput, render
from .sh import eval_sh

__all__ = ["render", "RenderOutput", "eval_sh"]

"""Rendering: the CPU Gaussian rasterizer, its gradients and spherical-harmonic colours."""

from .backward import RenderGradients, RenderWithGrad, render_with_grad
from .rasterizer import RenderOutput, render
from .sh import eval_sh

__all__ = ["render", "RenderOutput", "eval_sh", "render_with_grad", "RenderWithGrad", "RenderGradients"]

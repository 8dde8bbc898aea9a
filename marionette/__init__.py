"""Motion Marionette: rigid motion transfer from a monocular video onto a single image.

The library API, for scripts and notebooks::

    import marionette as mm

    prior = mm.extract("car.mp4")                      # source video → SpaT prior
    target = mm.lift_target("teapot.png", prior=prior)  # image or .ply → Gaussians + camera
    trajectory = mm.transfer(prior, target, speed=0.5)  # prior + target → per-frame Gaussians
    mm.render_video("teapot.mp4", target, trajectory, fps=prior.fps)
"""

from . import synthetic
from .camera import Camera
from .demo import write_demo_inputs
from .errors import InputError
from .gaussians import Gaussians
from .io import read_ply, read_prior, read_video, write_ply, write_prior, write_video
from .pipeline import extract, fit_view, render_frames, render_video, transfer, write_ply_frames
from .pipeline import load_target as lift_target
from .prior import SpatPrior
from .progress import Reporter
from .reconstruct import ReconstructOptions, Reconstruction, reconstruct_object
from .render import render
from .source import ExtractOptions
from .target.lift import LiftedTarget, LiftOptions
from .trajectory import Trajectory
from .transfer.metrics import trajectory_quality

__version__ = "0.1.0"

# `transfer` and `render` name both a function and a subpackage: the functions are bound after
# .pipeline has imported the subpackages, so `mm.transfer` and `mm.render` stay the functions.
__all__ = ["extract", "lift_target", "transfer", "render_video", "render_frames", "fit_view", "write_ply_frames",
           "render", "read_prior", "write_prior", "read_ply", "write_ply", "read_video", "write_video",
           "SpatPrior", "Gaussians", "Camera", "Trajectory", "LiftedTarget", "ExtractOptions", "LiftOptions",
           "Reporter", "InputError", "reconstruct_object", "ReconstructOptions", "Reconstruction", "trajectory_quality", "synthetic", "write_demo_inputs"]

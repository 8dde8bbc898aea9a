"""Motion Marionette: rigid motion transfer from a monocular video onto a single image.

The library API, for scripts and notebooks::

    import marionette as mm

    prior = mm.extract("car.mp4")                      # source video → SpaT prior
    target = mm.lift_target("teapot.png", prior=prior)  # image or .ply → Gaussians + camera
    trajectory = mm.transfer(prior, target, speed=0.5)  # prior + target → per-frame Gaussians
    mm.render_video("teapot.mp4", target, trajectory, fps=prior.fps)
"""

import importlib
import sys
import types

__version__ = "0.1.0"

#: Each name of the API: (module of this package, attribute; None for the module itself). Imported on first
#: use, so that ``import marionette`` and the command line start without loading every stage.
_API = {
    "extract": ("pipeline", "extract"),
    "lift_target": ("pipeline", "load_target"),
    "transfer": ("pipeline", "transfer"),
    "render_video": ("pipeline", "render_video"),
    "render_frames": ("pipeline", "render_frames"),
    "fit_view": ("pipeline", "fit_view"),
    "write_ply_frames": ("pipeline", "write_ply_frames"),
    "render": ("render", "render"),
    "read_prior": ("io", "read_prior"),
    "write_prior": ("io", "write_prior"),
    "read_ply": ("io", "read_ply"),
    "write_ply": ("io", "write_ply"),
    "read_video": ("io", "read_video"),
    "write_video": ("io", "write_video"),
    "SpatPrior": ("prior", "SpatPrior"),
    "Gaussians": ("gaussians", "Gaussians"),
    "Camera": ("camera", "Camera"),
    "Trajectory": ("trajectory", "Trajectory"),
    "LiftedTarget": ("target.lift", "LiftedTarget"),
    "ExtractOptions": ("source", "ExtractOptions"),
    "LiftOptions": ("target.lift", "LiftOptions"),
    "Reporter": ("progress", "Reporter"),
    "InputError": ("errors", "InputError"),
    "reconstruct_object": ("reconstruct", "reconstruct_object"),
    "ReconstructOptions": ("reconstruct", "ReconstructOptions"),
    "Reconstruction": ("reconstruct", "Reconstruction"),
    "trajectory_quality": ("transfer.metrics", "trajectory_quality"),
    "synthetic": ("synthetic", None),
    "write_demo_inputs": ("demo", "write_demo_inputs"),
}
__all__ = list(_API)


def __getattr__(name: str) -> object:
    try:
        module, attribute = _API[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = importlib.import_module(f".{module}", __name__)
    if attribute is not None:
        value = getattr(value, attribute)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """This package's module type: ``transfer`` and ``render`` stay the API's functions.

    Both also name a subpackage, and importing a subpackage binds it on its parent under its own name.
    """

    def __setattr__(self, name: str, value: object) -> None:
        if name in ("transfer", "render") and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

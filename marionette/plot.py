"""A picture of a SpaT prior: each part's rotation and centroid motion over time.

Drawn with matplotlib's object API on an Agg canvas (no pyplot, so no global
figure state), and written atomically.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError
from .geometry import matrix_to_axis_angle, rotation_angle_deg
from .io.atomic import atomic_path
from .prior import SpatPrior

__all__ = ["plot_prior"]

#: Figure size in inches and resolution: a 1000 x 900 pixel image.
FIGURE_SIZE = (10.0, 9.0)
DPI = 100
#: Rotations about the source camera's axes (x right, y down, z forward).
_ROTATION_AXES = ("pitch (about x)", "yaw (about y)", "roll (about z)")


def plot_prior(prior: SpatPrior, path: str | Path, *, title: str | None = None) -> None:
    """Write a PNG of each part's motion over time.

    The first row shows the rotation angle of ``poses[k, t]`` from frame 0
    (always >= 0). Below it, row by row for the camera axes x, y, z: on the
    left the signed rotation-vector component of ``poses[k, t]`` in the
    source camera frame (so a back-and-forth twist shows as a curve crossing
    zero), on the right the centroid displacement
    ``centroids[k, t] - centroids[k, 0]`` in units of the part's radius.
    Time is in seconds; each part is one colour.

    Parameters
    ----------
    prior : SpatPrior
    path : str or Path
        Output ``.png``; replaced only once the image is complete.
    title : str, optional
        Figure title; by default the part and frame counts.

    Raises
    ------
    InputError
        If ``path`` does not end in ``.png`` or its folder is missing or not writable.
    """
    if Path(path).suffix.lower() != ".png":
        raise InputError(f"plot path must end in .png, got {str(path)!r}")
    k_count, t_count = prior.num_parts, prior.num_frames
    seconds = np.arange(t_count) / prior.fps
    rotation = prior.poses[..., :3, :3]
    angle = rotation_angle_deg(rotation)  # (K, T)
    rotvec = np.degrees(matrix_to_axis_angle(rotation))  # (K, T, 3)
    shift = (prior.centroids - prior.centroids[:, :1]) / prior.radii[:, None, None]  # (K, T, 3)

    from matplotlib.figure import Figure  # imported here: matplotlib costs every command 0.9 s to load

    fig = Figure(figsize=FIGURE_SIZE, dpi=DPI, layout="constrained")
    axes = fig.subplots(4, 2, sharex=True)
    colors = [f"C{k % 10}" for k in range(k_count)]
    for k in range(k_count):
        label = f"part {k}" + (" (static)" if np.allclose(prior.poses[k], np.eye(4)) else "")
        axes[0, 0].plot(seconds, angle[k], color=colors[k], label=label)
        for i in range(3):
            axes[i + 1, 0].plot(seconds, rotvec[k, :, i], color=colors[k])
            axes[i + 1, 1].plot(seconds, shift[k, :, i], color=colors[k])
    axes[0, 0].set_ylabel("rotation angle (°)")
    axes[0, 0].set_ylim(bottom=0.0)
    for i, name in enumerate(_ROTATION_AXES):
        axes[i + 1, 0].set_ylabel(f"{name} (°)")
        axes[i + 1, 1].set_ylabel(f"centroid Δ{'xyz'[i]} (radii)")
    for ax in axes[1:].ravel():
        ax.axhline(0.0, color="0.6", linewidth=0.8, zorder=0)
    for ax in axes.ravel():
        ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    # The top-right cell holds the legend and what the rows mean.
    info = axes[0, 1]
    info.axis("off")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    info.legend(handles, labels, loc="upper left", ncols=1 + (k_count - 1) // 6, frameon=False)
    info.text(0.42, 0.95, "left: rotation from frame 0, then its\nsigned components in the source\ncamera frame "
              "(x right, y down,\nz forward)\n\nright: centroid displacement\nin units of the part radius",
              transform=info.transAxes, va="top", fontsize=9, color="0.3")
    fig.suptitle(title if title is not None else
                 f"SpaT prior: {k_count} part{'s' * (k_count > 1)}, {t_count} frames at {prior.fps:g} fps")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")

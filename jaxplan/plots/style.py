"""The look shared by every figure: sizes, the rc style, robot colours, figure creation
and atomic PNG saving, and the equal-scale axis limits of a run's paths."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from jaxplan.files import RunData, atomic_write
from jaxplan.plots.scene import world_extent

DPI = 120
ANIM_DPI = 100
FIGSIZE = {  # inches; x DPI = pixels
    "trajectories": (7.0, 6.0),
    "speed_acc": (8.0, 5.5),
    "separation": (11.0, 4.8),
    "clearance": (11.0, 4.8),
    "animation": (6.4, 4.8),
    "sweep_panel": (4.6, 4.0),
}
ANNOTATE_MAX = 8  # write the numbers into matrix / heatmap cells up to this many per side

STYLE = {
    "font.size": 10,
    "axes.titlesize": 11,
    "axes.labelsize": 10,
    "legend.fontsize": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "figure.facecolor": "white",
    "axes.facecolor": "white",
    "savefig.facecolor": "white",
}


def new_figure(size, dpi=DPI, layout="constrained"):
    fig = Figure(figsize=size, dpi=dpi, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def save_png(fig, path: Path) -> Path:
    """Save fig as PNG at exactly figsize x dpi pixels, atomically."""
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=fig.dpi))


def robot_colors(m: int) -> list:
    """One RGBA colour per robot: tab10 up to 10 robots, tab20 up to 20, else turbo."""
    if m <= 10:
        cmap = matplotlib.colormaps["tab10"]
        return [cmap(i) for i in range(m)]
    if m <= 20:
        cmap = matplotlib.colormaps["tab20"]
        return [cmap(i) for i in range(m)]
    cmap = matplotlib.colormaps["turbo"]
    return [cmap(x) for x in np.linspace(0.05, 0.95, m)]


def bounds(data: RunData, pad_frac=0.05):
    """Axis limits (N, 2) with equal scale on every axis: all positions and goals, padded
    by the largest radius, and the world's obstacles and nearby finite workspace faces
    (:func:`jaxplan.plots.scene.world_extent`; a moving obstacle along its path over the
    run); every range at least 20 % of the largest one."""
    pts = [data.pos.reshape(-1, data.ndim), data.goal]
    if data.waypoints is not None:
        w = data.waypoints.reshape(-1, data.ndim)
        pts.append(w[np.all(np.isfinite(w), axis=1)])
    p = np.concatenate(pts)
    lo = p.min(axis=0) - data.radius.max()
    hi = p.max(axis=0) + data.radius.max()
    lo, hi = world_extent(data.world, lo, hi, span=(data.t[0], data.t[-1]))
    span = hi - lo
    full = max(span.max(), 1e-6)
    span = np.maximum(span, 0.2 * full) * (1 + 2 * pad_frac)
    mid = 0.5 * (lo + hi)
    return np.stack([mid - span / 2, mid + span / 2], axis=1)


def apply_bounds(ax, lim, ndim):
    ax.set_xlim(*lim[0])
    ax.set_ylim(*lim[1])
    if ndim == 3:
        ax.set_zlim(*lim[2])
        ax.set_box_aspect(tuple(lim[:, 1] - lim[:, 0]), zoom=1.1)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
    else:
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")

"""Figures and animations of a run directory and of a sweep directory (docs/DESIGN.md,
"A run directory", "A sweep directory"): drawing only.

    plot_run(run_dir, *, animation=True, mp4=False, max_frames=150) -> list[Path]
    plot_sweep(sweep_dir) -> list[Path]

The data come from :func:`jaxplan.results.load_run` (a run directory, validated) and
:mod:`jaxplan.sweep_csv` (sweep.csv, its grid and best setting); the animation's frames
are encoded by :mod:`jaxplan.media`; every file is written atomically
(:mod:`jaxplan.fileio`).  Everything is drawn on :class:`matplotlib.figure.Figure`
objects with the Agg canvas; pyplot is never imported, the global backend is never
switched, and the style is applied inside ``matplotlib.rc_context`` only, so importing
or calling this module leaves no global matplotlib state behind.

Run figures (``run_dir/figures/``), sizes in pixels:

    trajectories_3d.png  840 x 720   paths in 3-D (equal aspect), starts o, goals ^,
                                     waypoints x; ``trajectories_2d.png`` for planar (N=2)
    speed_acc.png        960 x 660   |v| and |a| over time per robot, dotted limit lines
    separation.png      1320 x 576   d_ij(t) / rho_ij for every pair, the line at 1, each
                                     pair's minimum, the worst pair highlighted; and the
                                     M x M matrix of per-pair minimum ratios
    animation.gif        640 x 480   the fleet moving (<= max_frames frames, ~16.7 fps),
                                     markers scaled to the collision radius, 2 s trails;
                                     ``animation.mp4`` instead when mp4=True and ffmpeg
                                     is on PATH

Sweep figures (``sweep_dir/figures/``): ``success_rate.png``, ``min_separation.png``,
``makespan.png``; one panel per scenario group ("all scenarios", then each scenario when
there are several), 460 x 400 pixels per panel; the best setting
(:func:`jaxplan.sweep_csv.best_setting`) is outlined on every panel.

Bad input (a missing file or key, a wrong shape, non-finite numbers, an unreadable CSV
cell) raises ``ValueError("<file>: <key>: <problem>")`` before anything is drawn.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib import colors as mcolors
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from jaxplan import media
from jaxplan.fileio import atomic_write
from jaxplan.results import RunData, load_run
from jaxplan.sweep_csv import Grid, best_index, best_summary, grid, read_sweep_rows

__all__ = ["plot_run", "plot_sweep", "robot_colors"]

DPI = 120
ANIM_DPI = 100
FIGSIZE = {  # inches; x DPI = pixels
    "trajectories": (7.0, 6.0),
    "speed_acc": (8.0, 5.5),
    "separation": (11.0, 4.8),
    "animation": (6.4, 4.8),
    "sweep_panel": (4.6, 4.0),
}
FRAME_MS = 60  # GIF frame delay (a multiple of 10 ms, ~16.7 fps)
TRAIL_S = 2.0  # s of trail behind each robot in the animation
MAX_PAIR_LINES = 45  # draw every pair's curve up to this many pairs, else the envelope
ANNOTATE_MAX = 8  # write the numbers into matrix / heatmap cells up to this many per side

_STYLE = {
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


# ------------------------------------------------------------------------------ helpers


def _new_figure(size, dpi=DPI, layout="constrained"):
    fig = Figure(figsize=size, dpi=dpi, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _save_png(fig, path: Path) -> Path:
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


# --------------------------------------------------------------------------- run plots


def plot_run(run_dir, *, animation=True, mp4=False, max_frames=150) -> list[Path]:
    """Draw a run directory's figures into run_dir/figures/ (module docstring).

    Args:
        run_dir: a run directory (docs/DESIGN.md): trajectories.npz (required), metrics.json
            and config.toml (optional: title numbers and limits).
        animation: also write the animation (the slowest part: ~2-6 s).
        mp4: write animation.mp4 instead of animation.gif when ffmpeg is on PATH (a
            warning and the GIF otherwise).
        max_frames: the animation's frame bound (>= 2).

    Returns: the paths written, in the order trajectories, speed_acc, separation,
    animation.
    """
    data = load_run(run_dir)
    out = Path(run_dir) / "figures"
    paths = [
        _plot_trajectories(data, out),
        _plot_speed_acc(data, out),
        _plot_separation(data, out),
    ]
    if animation:
        paths.append(_animate(data, out, mp4=mp4, max_frames=max_frames))
    return paths


def _bounds(data: RunData, pad_frac=0.05):
    """Axis limits (N, 2) with equal scale on every axis: all positions and goals, padded
    by the largest radius, every range at least 20 % of the largest one."""
    pts = [data.pos.reshape(-1, data.ndim), data.goal]
    if data.waypoints is not None:
        w = data.waypoints.reshape(-1, data.ndim)
        pts.append(w[np.all(np.isfinite(w), axis=1)])
    p = np.concatenate(pts)
    lo = p.min(axis=0) - data.radius.max()
    hi = p.max(axis=0) + data.radius.max()
    span = hi - lo
    full = max(span.max(), 1e-6)
    span = np.maximum(span, 0.2 * full) * (1 + 2 * pad_frac)
    mid = 0.5 * (lo + hi)
    return np.stack([mid - span / 2, mid + span / 2], axis=1)


def _apply_bounds(ax, lim, ndim):
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


def _robot_label(data, i):
    return f"{i}: {data.vehicle[i]}" if data.vehicle[i] else f"robot {i}"


def _plot_trajectories(data: RunData, out: Path) -> Path:
    m, n = data.num_robots, data.ndim
    cols = robot_colors(m)
    lim = _bounds(data)
    with matplotlib.rc_context(_STYLE):
        fig = _new_figure(FIGSIZE["trajectories"])
        ax = fig.add_subplot(projection="3d" if n == 3 else None)
        for i in range(m):
            p = data.pos[i]
            ax.plot(*p.T, color=cols[i], lw=1.6, label=_robot_label(data, i))
            ax.plot(*p[0][:, None], ls="", marker="o", ms=7, mfc="white", mec=cols[i], mew=1.8)
            ax.plot(*data.goal[i][:, None], ls="", marker="^", ms=8, color=cols[i], mec="k",
                    mew=0.6)
            if data.waypoints is not None:
                w = data.waypoints[i]
                w = w[np.all(np.isfinite(w), axis=1)]
                w = w[~np.all(np.isclose(w, data.goal[i]), axis=1)]  # the goal has its ^
                if w.size:
                    ax.plot(*w.T, ls="", marker="x", ms=6, color=cols[i])
        _apply_bounds(ax, lim, n)
        if n == 3:
            ax.view_init(elev=25, azim=-60)
        handles = [
            Line2D([], [], ls="", marker="o", mfc="white", mec="0.3", mew=1.5, label="start"),
            Line2D([], [], ls="", marker="^", color="0.5", mec="k", mew=0.6, label="goal"),
        ]
        if data.waypoints is not None:
            handles.append(Line2D([], [], ls="", marker="x", color="0.3", label="waypoint"))
        robot_handles = ax.get_legend_handles_labels()[0] if m <= 12 else []
        fig.legend(handles=handles + robot_handles, loc="outside right upper", frameon=False)
        ttl = f"{data.name}: {m} robot{'s' if m != 1 else ''}, paths"
        if "success" in data.metrics:
            ttl += " (success)" if data.metrics["success"] else " (NOT successful)"
        ax.set_title(ttl)
        name = "trajectories_3d.png" if n == 3 else "trajectories_2d.png"
        return _save_png(fig, out / name)


def _plot_speed_acc(data: RunData, out: Path) -> Path:
    m = data.num_robots
    cols = robot_colors(m)
    speed = np.linalg.norm(data.vel, axis=2)
    accn = np.linalg.norm(data.acc, axis=2)
    with matplotlib.rc_context(_STYLE):
        fig = _new_figure(FIGSIZE["speed_acc"])
        axv, axa = fig.subplots(2, 1, sharex=True)
        for ax, val, key, sym, unit in (
            (axv, speed, "v_max", "|v|", "m/s"),
            (axa, accn, "a_max", "|a|", "m/s²"),
        ):
            for i in range(m):
                ax.plot(data.t, val[i], color=cols[i], lw=1.2, label=_robot_label(data, i))
            lims = data.limits[key]
            uniq = np.unique(lims[np.isfinite(lims)])
            for u in uniq:
                ax.axhline(u, color="k", ls=":", lw=1.4)
                ax.annotate(f"{key} = {u:g} {unit}", (1.0, u), xycoords=("axes fraction", "data"),
                            xytext=(-4, 3), textcoords="offset points", ha="right", va="bottom",
                            fontsize=8)
            peak = float(val.max()) if val.size else 0.0
            top = max(peak, uniq.max() if uniq.size else 0.0)
            ax.set_ylim(0, 1.12 * top if top > 0 else 1.0)
            ax.set_ylabel(f"{sym} [{unit}]")
            over = [i for i in range(m)
                    if np.isfinite(lims[i]) and val[i].max() > lims[i] * (1 + 1e-9)]
            note = f"peak {peak:.3g} {unit}"
            if over:
                note += f"; above {key}: robot{'s' if len(over) > 1 else ''} " + ", ".join(
                    map(str, over[:8])) + ("…" if len(over) > 8 else "")
            ax.set_title(f"{'Speed' if key == 'v_max' else 'Acceleration'} ({note})", loc="left")
        axa.set_xlabel("t [s]")
        if data.t.size > 1 and data.t[-1] > data.t[0]:
            axa.set_xlim(data.t[0], data.t[-1])
        if m <= 12:
            fig.legend(*axv.get_legend_handles_labels(), loc="outside right upper", frameon=False)
        fig.suptitle(f"{data.name}: speed and acceleration against the limits")
        return _save_png(fig, out / "speed_acc.png")


def _pair_minima(data: RunData):
    """(min_dist (M, M) m, t_min (M, M) s, exact: bool): from the pieces when present
    (metrics.pairwise_min_separation, exact), else from the samples."""
    m = data.num_robots
    if data.pieces is not None:
        from jaxplan.metrics import pairwise_min_separation

        try:
            d, tm = pairwise_min_separation(*data.pieces, num_robots=m)
        except ValueError as e:
            raise ValueError(f"{data.run_dir / 'trajectories.npz'}: seg_*: {e}") from None
        return d, tm, True
    d = np.full((m, m), np.inf)
    tm = np.full((m, m), np.nan)
    for i in range(m):
        for j in range(i + 1, m):
            dij = np.linalg.norm(data.pos[i] - data.pos[j], axis=1)
            k = int(np.argmin(dij))
            d[i, j] = d[j, i] = dij[k]
            tm[i, j] = tm[j, i] = data.t[k]
    return d, tm, False


@dataclass(frozen=True)
class _PairMinima:
    """Each pair's minimum separation ratio, from :func:`_pair_minima`.

    ratio (M, M): min d_ij / rho_ij (inf on the diagonal and where unknown); t (M, M) s:
    when; iu, ju (P,): the pairs i < j; pair_min (P,): ratio at the pairs; worst: the index
    into the pairs of the smallest finite minimum, or None; exact: from the pieces."""

    ratio: np.ndarray
    t: np.ndarray
    iu: np.ndarray
    ju: np.ndarray
    pair_min: np.ndarray
    worst: int | None
    exact: bool

    @property
    def worst_pair(self):
        return None if self.worst is None else (int(self.iu[self.worst]), int(self.ju[self.worst]))

    @property
    def source(self) -> str:
        return "exact" if self.exact else "sampled"


def _pair_ratios(data: RunData, rho) -> _PairMinima:
    d, tm, exact = _pair_minima(data)
    with np.errstate(invalid="ignore"):
        ratio = np.where(np.isfinite(d), d / rho, np.inf)
    iu, ju = np.triu_indices(data.num_robots, k=1)
    pair_min = ratio[iu, ju]
    finite = np.isfinite(pair_min)
    worst = int(np.argmin(np.where(finite, pair_min, np.inf))) if np.any(finite) else None
    return _PairMinima(ratio, tm, iu, ju, pair_min, worst, exact)


def _plot_separation(data: RunData, out: Path) -> Path:
    """separation.png: the ratio curves over time (left), the per-pair minima (right)."""
    with matplotlib.rc_context(_STYLE):
        fig = _new_figure(FIGSIZE["separation"])
        if data.num_robots < 2:
            ax = fig.add_subplot()
            ax.text(0.5, 0.5, "a single robot: no pairs to separate", ha="center", va="center",
                    transform=ax.transAxes)
            ax.set_axis_off()
            return _save_png(fig, out / "separation.png")
        gs = fig.add_gridspec(1, 2, width_ratios=(2.6, 1))
        ax = fig.add_subplot(gs[0])
        axm = fig.add_subplot(gs[1])
        rho = data.radius[:, None] + data.radius[None, :]
        pm = _pair_ratios(data, rho)
        _draw_separation_curves(ax, data, rho, pm)
        ax.set_title(_separation_title(data, pm), loc="left")
        _draw_minimum_matrix(fig, axm, data.num_robots, pm)
        return _save_png(fig, out / "separation.png")


def _draw_separation_curves(ax, data: RunData, rho, pm: _PairMinima) -> None:
    """d_ij(t) / rho_ij: every pair (thin, grey) or the envelope over pairs, each pair's
    minimum, the contact line at 1, the worst pair in red."""
    iu, ju, pair_min, k = pm.iu, pm.ju, pm.pair_min, pm.worst
    finite = np.isfinite(pair_min)

    def curve(i, j):
        return np.linalg.norm(data.pos[i] - data.pos[j], axis=1) / rho[i, j]

    top = 0.0
    if iu.size <= MAX_PAIR_LINES:
        for i, j in zip(iu, ju, strict=True):
            c = curve(i, j)
            top = max(top, float(c.max()))
            ax.plot(data.t, c, color="0.55", lw=0.8, alpha=0.6)
        env_label = "other pairs"
    else:
        env = np.full(data.t.size, np.inf)
        for i, j in zip(iu, ju, strict=True):
            c = curve(i, j)
            top = max(top, float(c.max()))
            env = np.minimum(env, c)
        ax.plot(data.t, env, color="0.35", lw=1.0)
        env_label = f"min over the {iu.size} pairs"
    handles = [Line2D([], [], color="0.45", lw=1.0, label=env_label)]
    ax.axhspan(0, 1, color="tab:red", alpha=0.07, lw=0)
    ax.axhline(1.0, color="k", ls="--", lw=1.2)
    handles.append(Line2D([], [], color="k", ls="--", lw=1.2, label="d = ρ (contact)"))
    if np.any(finite):
        ms, alpha = (3.5, 1.0) if iu.size <= MAX_PAIR_LINES else (2.0, 0.5)
        ax.plot(pm.t[iu, ju][finite], pair_min[finite], ls="", marker="o", ms=ms,
                color="0.25", alpha=alpha, zorder=3)
        handles.append(Line2D([], [], ls="", marker="o", ms=3.5, color="0.25",
                              label=f"minimum of each pair ({pm.source})"))
    low = 1.0
    if k is not None:
        i, j = pm.worst_pair
        ax.plot(data.t, curve(i, j), color="tab:red", lw=2.0, zorder=4)
        ax.plot([pm.t[i, j]], [pair_min[k]], ls="", marker="o", ms=7, mfc="tab:red",
                mec="k", zorder=5)
        handles.append(Line2D([], [], color="tab:red", lw=2.0,
                              label=f"worst pair ({i}, {j}): {pair_min[k]:.3f} "
                                    f"at t = {pm.t[i, j]:.2f} s"))
        low = float(pair_min[k])
    ax.set_ylim(0, min(max(top, 1.2) * 1.03, max(3.0, 2.0 * low)))
    if data.t.size > 1 and data.t[-1] > data.t[0]:
        ax.set_xlim(data.t[0], data.t[-1])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("d_ij / ρ_ij  (ρ_ij = r_i + r_j)")
    ax.legend(handles=handles, loc="upper right", framealpha=0.9)


def _separation_title(data: RunData, pm: _PairMinima) -> str:
    """The curves' title: the minimum found here, metrics.json's, the colliding pairs."""
    title = "Pairwise separation ratio"
    v = data.metrics.get("min_separation_ratio")
    if pm.worst is not None:
        title += f": min {pm.pair_min[pm.worst]:.4f} ({pm.source})"
    if isinstance(v, int | float) and not isinstance(v, bool):
        title += f"{',' if pm.worst is not None else ':'} {v:.4f} in metrics.json"
    c = data.metrics.get("collisions")
    if isinstance(c, int) and not isinstance(c, bool):
        title += f", {c} colliding pair{'s' if c != 1 else ''}"
    return title


def _draw_minimum_matrix(fig, axm, m: int, pm: _PairMinima) -> None:
    """The M x M matrix of per-pair minimum ratios, the worst pair outlined."""
    mat = np.where(np.isfinite(pm.ratio), pm.ratio, np.nan)
    np.fill_diagonal(mat, np.nan)
    fin = mat[np.isfinite(mat)]
    vmin = min(0.5, float(fin.min())) if fin.size else 0.5
    vmax = max(2.0, float(fin.max())) if fin.size else 2.0
    norm = mcolors.TwoSlopeNorm(vmin=vmin, vcenter=1.0, vmax=vmax)
    cmap = matplotlib.colormaps["RdBu"].with_extremes(bad="0.92")
    im = axm.imshow(mat, cmap=cmap, norm=norm, origin="upper")
    axm.grid(False)
    if m <= ANNOTATE_MAX:
        for i, j in zip(*np.nonzero(np.isfinite(mat)), strict=True):
            axm.text(j, i, f"{mat[i, j]:.2f}", ha="center", va="center", fontsize=7,
                     color="w" if abs(norm(mat[i, j]) - 0.5) > 0.35 else "k")
    if pm.worst is not None:
        i, j = pm.worst_pair
        for a, b in ((i, j), (j, i)):
            axm.add_patch(Rectangle((b - 0.5, a - 0.5), 1, 1, fill=False, ec="k", lw=2))
    ticks = np.arange(m) if m <= 20 else np.linspace(0, m - 1, 6).round().astype(int)
    axm.set_xticks(ticks)
    axm.set_yticks(ticks)
    axm.set_xlabel("robot j")
    axm.set_ylabel("robot i")
    axm.set_title(f"min d_ij / ρ_ij per pair ({pm.source})", loc="left")
    fig.colorbar(im, ax=axm, shrink=0.85)


# --------------------------------------------------------------------------- animation


def _frame_times(t, max_frames):
    dur = float(t[-1] - t[0])
    realtime = int(math.ceil(dur * 1000.0 / FRAME_MS)) + 1
    nf = max(2, min(int(max_frames), realtime))
    return np.linspace(t[0], t[-1], nf)


def _interp(t, x, tf):
    """x (M, K, N) sampled at t (K,) -> (M, F, N) at tf (F,), linear."""
    m, _, n = x.shape
    out = np.empty((m, tf.size, n))
    for i in range(m):
        for d in range(n):
            out[i, :, d] = np.interp(tf, t, x[i, :, d])
    return out


def _to_pixels(ax, pts):
    """Positions pts (..., N) m -> display pixels (..., 2) and depth (...,) (larger is
    farther; zeros in 2-D), for an axes whose view is fixed (after a draw)."""
    flat = pts.reshape(-1, pts.shape[-1])
    if pts.shape[-1] == 3:
        from mpl_toolkits.mplot3d import proj3d

        x, y, z = proj3d.proj_transform(flat[:, 0], flat[:, 1], flat[:, 2], ax.M)
        xy, depth = np.column_stack([x, y]), np.asarray(z)
    else:
        xy, depth = flat, np.zeros(flat.shape[0])
    px = ax.transData.transform(xy)
    return px.reshape(pts.shape[:-1] + (2,)), depth.reshape(pts.shape[:-1])


def _px_per_m(ax, lim):
    """Pixels per metre of an equal-aspect axes (orthographic in 3-D), after a draw: the
    largest singular value of the projection of the unit axes."""
    c = lim.mean(axis=1)
    step = 0.25 * float((lim[:, 1] - lim[:, 0]).min())
    pts = np.vstack([c, c + step * np.eye(c.size)])
    px, _ = _to_pixels(ax, pts)
    jac = (px[1:] - px[0]).T / step  # (2, N)
    return float(np.linalg.svd(jac, compute_uv=False)[0])


def _animate(data: RunData, out: Path, *, mp4: bool, max_frames: int) -> Path:
    """Render the animation.  The static scene (axes, faint full paths, goals) is drawn
    once; every frame restores it and draws three artists on top: the trails (one
    LineCollection), the bodies (one EllipseCollection, discs of the collision radius,
    back to front) and the clock.  Positions are projected to pixels once, up front
    (orthographic 3-D view, equal aspect): ~5-10 ms per 640 x 480 frame."""
    if int(max_frames) < 2:
        raise ValueError(f"max_frames must be >= 2; got {max_frames}")
    use_mp4 = False
    if mp4:
        if media.ffmpeg_available():
            use_mp4 = True
        else:
            warnings.warn("ffmpeg not found on PATH: writing animation.gif instead of .mp4",
                          stacklevel=3)
    from matplotlib.collections import EllipseCollection
    from matplotlib.transforms import IdentityTransform

    m, n = data.num_robots, data.ndim
    cols = np.asarray(robot_colors(m))
    lim = _bounds(data)
    tf = _frame_times(data.t, max_frames)
    pf = _interp(data.t, data.pos, tf)  # (M, F, N)
    with matplotlib.rc_context(_STYLE):
        fig = _new_figure(FIGSIZE["animation"], dpi=ANIM_DPI, layout=None)
        fig.subplots_adjust(left=0.02 if n == 3 else 0.12, right=0.98,
                            bottom=0.08 if n == 3 else 0.11, top=0.92)
        ax = fig.add_subplot(projection="3d" if n == 3 else None)
        _apply_bounds(ax, lim, n)
        if n == 3:
            ax.set_proj_type("ortho")
            ax.view_init(elev=25, azim=-60)
        for i in range(m):
            ax.plot(*data.pos[i].T, color=cols[i], lw=0.8, alpha=0.2)
            ax.plot(*data.goal[i][:, None], ls="", marker="^", ms=6, color=cols[i], mec="k",
                    mew=0.5, alpha=0.8)
        fig.text(0.97, 0.95, f"{data.name}: {m} robot{'s' if m != 1 else ''}", fontsize=9,
                 ha="right", va="top")
        canvas = fig.canvas
        canvas.draw()  # fixes the layout and the view: from here on, project once
        background = canvas.copy_from_bbox(fig.bbox)
        pix, _ = _to_pixels(ax, data.pos)  # (M, K, 2)
        fpix, fdepth = _to_pixels(ax, pf)  # (M, F, 2), (M, F)
        diam = 2.0 * data.radius * _px_per_m(ax, lim)  # (M,) pixels
        ident = IdentityTransform()
        trails = LineCollection([], colors=cols, linewidths=1.8, transform=ident,
                                animated=True)
        bodies = EllipseCollection(diam, diam, np.zeros(m), units="dots", offsets=fpix[:, 0],
                                   offset_transform=ident, facecolors=cols, edgecolors="k",
                                   linewidths=0.5, alpha=0.85, animated=True)
        for art in (trails, bodies):
            fig.add_artist(art)
        label = fig.text(0.03, 0.95, "", fontsize=11, family="monospace", va="top",
                         animated=True)
        bbox = ax.get_window_extent()
        trails.set_clip_box(bbox)
        bodies.set_clip_box(bbox)

        def frames():
            """Yield each frame as a fresh (H, W, 4) uint8 RGBA array."""
            for f, tt in enumerate(tf):
                hi = int(np.searchsorted(data.t, tt, side="right"))
                lo = int(np.searchsorted(data.t, tt - TRAIL_S, side="left"))
                canvas.restore_region(background)
                trails.set_segments(
                    [np.concatenate([pix[i, lo:hi], fpix[i, f][None]]) for i in range(m)])
                order = np.argsort(-fdepth[:, f], kind="stable")  # far to near
                bodies.set_offsets(fpix[order, f])
                bodies.set_widths(diam[order])
                bodies.set_heights(diam[order])
                bodies.set_facecolor(cols[order])
                fig.draw_artist(trails)
                fig.draw_artist(bodies)
                label.set_text(f"t = {tt:6.2f} s")
                fig.draw_artist(label)
                yield np.array(canvas.buffer_rgba(), copy=True)

        size = canvas.get_width_height()
        if use_mp4:
            return media.write_mp4(frames(), size, out / "animation.mp4", FRAME_MS)
        return media.write_gif(frames(), out / "animation.gif", FRAME_MS)


# -------------------------------------------------------------------------------- sweeps

def _log_edges(v):
    """Cell edges of sorted positive values on a log axis (geometric midpoints)."""
    lv = np.log10(v)
    if lv.size == 1:
        e = np.array([lv[0] - 0.5, lv[0] + 0.5])
    else:
        mid = 0.5 * (lv[1:] + lv[:-1])
        e = np.concatenate([[lv[0] - (mid[0] - lv[0])], mid, [lv[-1] + (lv[-1] - mid[-1])]])
    return 10.0**e


def _lin_edges(v):
    if v.size == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])


def _fmt_q(v):
    if v > 0:
        e = math.log10(v)
        if abs(e - round(e)) < 1e-9:
            return f"$10^{{{int(round(e))}}}$"
    return f"{v:.3g}"


_SWEEP_FIGS = (
    ("success_rate.png", "success", "success rate", "viridis"),
    ("min_separation.png", "min_sep", "min separation ratio d/ρ (worst over seeds)", "RdBu"),
    ("makespan.png", "makespan", "makespan [s] (mean over successful runs)", "cividis"),
)


def plot_sweep(sweep_dir) -> list[Path]:
    """Heatmaps of a sweep over the (q_obs, q_lim) grid into sweep_dir/figures/.

    Reads sweep_dir/sweep.csv (columns at least q_obs, q_lim, scenario, seed, success,
    min_separation_ratio, makespan_s, collisions).  Writes success_rate.png (mean over
    seeds), min_separation.png (worst over seeds, contour and hatching at ratio 1) and
    makespan.png (mean over successful runs; grey where none succeeded): one panel for
    all scenarios together, plus one per scenario when there are several.  Axes are
    log10 when every weight is positive.  The best setting
    (:func:`jaxplan.sweep_csv.best_setting`) is outlined in black on every panel.

    Returns: the three paths.
    """
    sweep_dir = Path(sweep_dir)
    path = sweep_dir / "sweep.csv"
    rows = read_sweep_rows(path)
    everything = np.ones(rows.q_obs.size, dtype=bool)
    groups = [("all scenarios", everything)]
    scen = list(dict.fromkeys(rows.scenario.tolist()))
    if len(scen) > 1:
        groups += [(s, rows.scenario == s) for s in scen]
    else:
        groups = [(scen[0] or "all scenarios", everything)]
    grids = [(name, grid(rows, mask)) for name, mask in groups]
    g_all = grids[0][1] if len(scen) <= 1 else grid(rows, everything)
    best = best_index(g_all)
    bq = (g_all.q_obs[best[0]], g_all.q_lim[best[1]])
    n_seeds = len(set(rows.seed.tolist()))

    out = []
    for fname, field, label, cmap_name in _SWEEP_FIGS:
        with matplotlib.rc_context({**_STYLE, "axes.grid": False}):
            w, h = FIGSIZE["sweep_panel"]
            fig = _new_figure((w * len(grids), h))
            axes = np.atleast_1d(fig.subplots(1, len(grids), squeeze=False)[0])
            vals = np.concatenate([getattr(gr, field).ravel() for _, gr in grids])
            fin = vals[np.isfinite(vals)]
            cmap = matplotlib.colormaps[cmap_name].with_extremes(bad="0.85")
            if field == "success":
                norm = mcolors.Normalize(0.0, 1.0)
            elif field == "min_sep":
                lo = min(0.5, float(fin.min())) if fin.size else 0.5
                hi = max(1.5, float(fin.max())) if fin.size else 1.5
                norm = mcolors.TwoSlopeNorm(vmin=lo, vcenter=1.0, vmax=hi)
            else:
                lo, hi = (float(fin.min()), float(fin.max())) if fin.size else (0.0, 1.0)
                norm = mcolors.Normalize(lo, hi if hi > lo else lo + 1.0)
            for ax, (name, gr) in zip(axes, grids, strict=True):
                z = getattr(gr, field)
                _heatmap(ax, gr, z, cmap, norm, field, bq)
                ax.set_title(name, loc="left")
            im = axes[0].collections[0]
            fig.colorbar(im, ax=list(axes), label=label, shrink=0.9)
            bs = best_summary(g_all, best)
            fig.suptitle(f"{sweep_dir.name}: {label}\n{rows.q_obs.size} runs, {n_seeds} "
                         f"seed{'s' if n_seeds != 1 else ''}; best {bs}", fontsize=9)
            out.append(_save_png(fig, sweep_dir / "figures" / fname))
    return out


def _heatmap(ax, gr: Grid, z, cmap, norm, field, best_q):
    logx = bool(np.all(gr.q_obs > 0))
    logy = bool(np.all(gr.q_lim > 0))
    xe = _log_edges(gr.q_obs) if logx else _lin_edges(gr.q_obs)
    ye = _log_edges(gr.q_lim) if logy else _lin_edges(gr.q_lim)
    # rows of z are q_obs (x), columns q_lim (y): pcolormesh wants (y, x)
    zm = np.ma.masked_invalid(z.T)
    ax.pcolormesh(xe, ye, zm, cmap=cmap, norm=norm, edgecolors="w", linewidth=0.5)
    if logx:
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    ax.set_xticks(gr.q_obs, [_fmt_q(v) for v in gr.q_obs])
    ax.set_yticks(gr.q_lim, [_fmt_q(v) for v in gr.q_lim])
    ax.minorticks_off()
    ax.set_xlim(xe[0], xe[-1])
    ax.set_ylim(ye[0], ye[-1])
    ax.set_xlabel("q_obs" + (" (log scale)" if logx else ""))
    ax.set_ylabel("q_lim" + (" (log scale)" if logy else ""))
    if gr.q_obs.size <= 12 and gr.q_lim.size <= 12:
        for a in range(gr.q_obs.size):
            for b in range(gr.q_lim.size):
                v = z[a, b]
                if gr.runs[a, b] == 0:
                    txt = "no run"
                elif not np.isfinite(v):
                    txt = "—"
                elif field == "success":
                    txt = f"{100 * v:.0f}%"
                elif field == "min_sep":
                    txt = f"{v:.2f}"
                else:
                    txt = f"{v:.1f}"
                shade = norm(v) if np.isfinite(v) else 0.5
                dark = cmap(shade)[:3]
                lum = 0.299 * dark[0] + 0.587 * dark[1] + 0.114 * dark[2]
                ax.text(gr.q_obs[a], gr.q_lim[b], txt, ha="center", va="center", fontsize=8,
                        color="w" if lum < 0.45 else "k", zorder=3,
                        bbox=dict(boxstyle="round,pad=0.15", ec="none",
                                  fc=cmap(shade) if np.isfinite(v) else "0.85"))
    if field == "min_sep":
        # hatch the colliding cells (ratio < 1) and draw the contour at 1 along cell edges
        below = np.isfinite(z) & (z < 1.0)
        above = np.isfinite(z) & (z >= 1.0)
        for a in range(gr.q_obs.size):
            for b in range(gr.q_lim.size):
                if below[a, b]:
                    ax.add_patch(Rectangle((xe[a], ye[b]), xe[a + 1] - xe[a], ye[b + 1] - ye[b],
                                           fill=False, hatch="//", ec=(0, 0, 0, 0.3), lw=0))
        segs = []
        for a in range(gr.q_obs.size):
            for b in range(gr.q_lim.size):
                if a + 1 < gr.q_obs.size and ((below[a, b] and above[a + 1, b])
                                              or (above[a, b] and below[a + 1, b])):
                    segs.append([(xe[a + 1], ye[b]), (xe[a + 1], ye[b + 1])])
                if b + 1 < gr.q_lim.size and ((below[a, b] and above[a, b + 1])
                                              or (above[a, b] and below[a, b + 1])):
                    segs.append([(xe[a], ye[b + 1]), (xe[a + 1], ye[b + 1])])
        if segs:
            ax.add_collection(LineCollection(segs, colors="k", linewidths=2.2, linestyles="--",
                                             zorder=4, label="d/ρ = 1"))
    if best_q is not None and best_q[0] in gr.q_obs and best_q[1] in gr.q_lim:
        a = int(np.nonzero(gr.q_obs == best_q[0])[0][0])
        b = int(np.nonzero(gr.q_lim == best_q[1])[0][0])
        ax.add_patch(Rectangle((xe[a], ye[b]), xe[a + 1] - xe[a], ye[b + 1] - ye[b], fill=False,
                               ec="k", lw=2.5, zorder=5))
        ax.annotate("best", (gr.q_obs[a], ye[b + 1]), xytext=(0, -2), textcoords="offset points",
                    ha="center", va="top", fontsize=7, fontweight="bold", zorder=6)

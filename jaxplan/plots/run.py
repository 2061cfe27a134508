"""The static figures of a run directory: paths (3-D and top views) in the run's world
(a moving obstacle where it starts, with its path: :mod:`jaxplan.plots.scene`), speed
and acceleration against the limits, pairwise separation, clearance to the
obstacles and the workspace (:func:`plot_run`; the sizes are in :mod:`jaxplan.plots`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib import colors as mcolors
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from jaxplan.files import RunData, load_run
from jaxplan.plots.scene import (
    OBSTACLE_EDGE,
    OBSTACLE_FACE,
    PATH_STYLE,
    WALL,
    clearances,
    draw_world_2d,
    draw_world_3d,
)
from jaxplan.plots.style import (
    ANNOTATE_MAX,
    FIGSIZE,
    STYLE,
    apply_bounds,
    bounds,
    new_figure,
    robot_colors,
    save_png,
)
from jaxplan.world import face_names

MAX_PAIR_LINES = 45  # draw every pair's curve up to this many pairs, else the envelope


def plot_run(run_dir, *, animation=True, mp4=False, max_frames=150) -> list[Path]:
    """Draw a run directory's figures into run_dir/figures/ (module docstring).

    Args:
        run_dir: a run directory (docs/DESIGN.md): trajectories.npz (required), metrics.json
            and config.toml (optional: title numbers and limits).
        animation: also write the animation (the slowest part).
        mp4: write animation.mp4 instead of animation.gif when ffmpeg is on PATH (a
            warning and the GIF otherwise).
        max_frames: the animation's frame bound (>= 2).

    Returns: the paths written, in the order trajectories, trajectories_top (3-D runs),
    speed_acc, separation, clearance, animation.
    """
    data = load_run(run_dir)
    out = Path(run_dir) / "figures"
    paths = [_plot_trajectories(data, out)]
    if data.ndim == 3:
        paths.append(_plot_top_view(data, out))
    paths += [
        _plot_speed_acc(data, out),
        _plot_separation(data, out),
        _plot_clearance(data, out),
    ]
    if animation:
        from jaxplan.plots.animation import animate

        paths.append(animate(data, out, mp4=mp4, max_frames=max_frames))
    return paths


def _robot_label(data, i):
    label = f"{i}: {data.vehicle[i]}" if data.vehicle[i] else f"robot {i}"
    coop = getattr(data, "cooperative", None)
    return label if coop is None or coop[i] else f"{label} (non-cooperative)"


def _plot_trajectories(data: RunData, out: Path) -> Path:
    m, n = data.num_robots, data.ndim
    cols = robot_colors(m)
    lim = bounds(data)
    with matplotlib.rc_context(STYLE):
        fig = new_figure(FIGSIZE["trajectories"])
        ax = fig.add_subplot(projection="3d" if n == 3 else None)
        span = (data.t[0], data.t[-1])  # a moving obstacle at its start, and its path
        if n == 3:
            draw_world_3d(ax, data.world, lim, span)
        else:
            draw_world_2d(ax, data.world, lim, span)
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
        apply_bounds(ax, lim, n)
        if n == 3:
            ax.view_init(elev=25, azim=-60)
        handles = [
            Line2D([], [], ls="", marker="o", mfc="white", mec="0.3", mew=1.5, label="start"),
            Line2D([], [], ls="", marker="^", color="0.5", mec="k", mew=0.6, label="goal"),
        ]
        if data.waypoints is not None:
            handles.append(Line2D([], [], ls="", marker="x", color="0.3", label="waypoint"))
        handles += _world_handles(data.world)
        robot_handles = ax.get_legend_handles_labels()[0] if m <= 12 else []
        fig.legend(handles=handles + robot_handles, loc="outside right upper", frameon=False)
        ttl = f"{data.name}: {m} robot{'s' if m != 1 else ''}, paths"
        if "success" in data.metrics:
            ttl += " (success)" if data.metrics["success"] else " (NOT successful)"
        ax.set_title(ttl)
        name = "trajectories_3d.png" if n == 3 else "trajectories_2d.png"
        return save_png(fig, out / name)


def _world_handles(world, axes: int = 3) -> list:
    """Legend entries of the world's obstacles, moving obstacles' paths and faces (of its
    first ``axes`` axes); none without them."""
    out = []
    if world is None:
        return out
    if world.num_obstacles:
        out.append(Patch(facecolor=OBSTACLE_FACE, edgecolor=OBSTACLE_EDGE, alpha=0.6,
                         label=f"obstacle{'s' if world.num_obstacles > 1 else ''}"))
    if world.has_motion:
        out.append(Line2D([], [], marker=">", ms=5, mfc=OBSTACLE_EDGE, mec=OBSTACLE_EDGE,
                          label="moving obstacle: start, path", **PATH_STYLE))
    if np.any(np.isfinite(world.lo[:axes])) or np.any(np.isfinite(world.hi[:axes])):
        out.append(Patch(facecolor=WALL, alpha=0.3, label="workspace face"))
    return out


def _plot_top_view(data: RunData, out: Path) -> Path:
    """trajectories_top.png: the x-y projection of a 3-D run, with the obstacles'
    footprints and the finite x, y workspace faces."""
    m = data.num_robots
    cols = robot_colors(m)
    lim = bounds(data)[:2]
    with matplotlib.rc_context(STYLE):
        fig = new_figure(FIGSIZE["trajectories"])
        ax = fig.add_subplot()
        draw_world_2d(ax, data.world, lim, (data.t[0], data.t[-1]))
        for i in range(m):
            p = data.pos[i]
            ax.plot(p[:, 0], p[:, 1], color=cols[i], lw=1.6, label=_robot_label(data, i),
                    zorder=2)
            ax.plot(*p[0, :2], ls="", marker="o", ms=7, mfc="white", mec=cols[i], mew=1.8,
                    zorder=3)
            ax.plot(*data.goal[i, :2], ls="", marker="^", ms=8, color=cols[i], mec="k",
                    mew=0.6, zorder=3)
        apply_bounds(ax, lim, 2)
        handles = [
            Line2D([], [], ls="", marker="o", mfc="white", mec="0.3", mew=1.5, label="start"),
            Line2D([], [], ls="", marker="^", color="0.5", mec="k", mew=0.6, label="goal"),
            *_world_handles(data.world, axes=2),
        ]
        robot_handles = ax.get_legend_handles_labels()[0] if m <= 12 else []
        fig.legend(handles=handles + robot_handles, loc="outside right upper", frameon=False)
        ax.set_title(f"{data.name}: top view (x-y)")
        return save_png(fig, out / "trajectories_top.png")


def _plot_clearance(data: RunData, out: Path) -> Path:
    """clearance.png: each robot's clearance (signed distance - radius, min over the
    obstacles; beside it, min over the finite workspace faces) over time, the line at 0,
    the worst instant marked (:func:`jaxplan.plots.scene.clearances`)."""
    obs, ws = clearances(data.world, data.pos, data.radius, data.t)
    panels = [(c, what) for c, what in ((obs, "obstacle"), (ws, "workspace"))
              if c.shape[-1]]
    with matplotlib.rc_context(STYLE):
        fig = new_figure(FIGSIZE["clearance"])
        if not panels:
            ax = fig.add_subplot()
            ax.text(0.5, 0.5, "no obstacles and an unbounded workspace: no clearance",
                    ha="center", va="center", transform=ax.transAxes)
            ax.set_axis_off()
            return save_png(fig, out / "clearance.png")
        axes = fig.subplots(1, len(panels), sharey=False, squeeze=False)[0]
        for ax, (c, what) in zip(axes, panels, strict=True):
            _draw_clearance(ax, data, c, what)
        if data.num_robots <= 12:
            fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper",
                       frameon=False)
        fig.suptitle(f"{data.name}: clearance to the world (from the samples)")
        return save_png(fig, out / "clearance.png")


def _draw_clearance(ax, data: RunData, c, what: str) -> None:
    """One panel: min over the rows of c (M, K, R) per robot over time, the zero line, the
    worst (robot, row, time) in red, metrics.json's figures in the title."""
    m = data.num_robots
    cols = robot_colors(m)
    per_robot = c.min(axis=2)  # (M, K)
    for i in range(m):
        ax.plot(data.t, per_robot[i], color=cols[i], lw=1.2, label=_robot_label(data, i))
    ax.axhspan(min(0.0, float(per_robot.min())) - 1.0, 0.0, color="tab:red", alpha=0.07,
               lw=0)
    ax.axhline(0.0, color="k", ls="--", lw=1.2)
    i, k, j = np.unravel_index(int(np.argmin(c)), c.shape)
    worst = float(c[i, k, j])
    rows = (list(range(c.shape[2])) if what == "obstacle" else face_names(data.world))
    ax.plot([data.t[k]], [worst], ls="", marker="o", ms=7, mfc="tab:red", mec="k", zorder=5)
    row = f"obstacle {rows[j]}" if what == "obstacle" else f"face {rows[j]}"
    right = data.t[-1] > data.t[0] and data.t[k] > 0.6 * data.t[-1] + 0.4 * data.t[0]
    ax.annotate(f"robot {i}, {row}: {worst:.3f} m at t = {data.t[k]:.2f} s", (data.t[k], worst),
                xytext=(-8 if right else 8, 8), textcoords="offset points", fontsize=8,
                color="tab:red", ha="right" if right else "left",
                bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.8))
    top = max(float(per_robot.max()), 0.5)
    ax.set_ylim(min(-0.1, 1.15 * worst) if worst < 0 else -0.1 * top, top * 1.08)
    if data.t.size > 1 and data.t[-1] > data.t[0]:
        ax.set_xlim(data.t[0], data.t[-1])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("signed distance - radius [m]")
    title = "Obstacle clearance (min over obstacles)" if what == "obstacle" else \
        "Workspace clearance (min over faces)"
    count, key = (("obstacle_collisions", "min_obstacle_clearance_m") if what == "obstacle"
                  else ("workspace_violations", "min_workspace_clearance_m"))
    v = data.metrics.get(key)
    if isinstance(v, int | float) and not isinstance(v, bool):
        title += f"\nmetrics.json: min {v:.4f} m"
        n = data.metrics.get(count)
        if isinstance(n, int) and not isinstance(n, bool):
            title += f", {n} {'contact' if what == 'obstacle' else 'violation'}" \
                     f"{'s' if n != 1 else ''}"
    ax.set_title(title, loc="left")


def _plot_speed_acc(data: RunData, out: Path) -> Path:
    m = data.num_robots
    cols = robot_colors(m)
    speed = np.linalg.norm(data.vel, axis=2)
    accn = np.linalg.norm(data.acc, axis=2)
    with matplotlib.rc_context(STYLE):
        fig = new_figure(FIGSIZE["speed_acc"])
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
        return save_png(fig, out / "speed_acc.png")


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
    with matplotlib.rc_context(STYLE):
        fig = new_figure(FIGSIZE["separation"])
        if data.num_robots < 2:
            ax = fig.add_subplot()
            ax.text(0.5, 0.5, "a single robot: no pairs to separate", ha="center", va="center",
                    transform=ax.transAxes)
            ax.set_axis_off()
            return save_png(fig, out / "separation.png")
        gs = fig.add_gridspec(1, 2, width_ratios=(2.6, 1))
        ax = fig.add_subplot(gs[0])
        axm = fig.add_subplot(gs[1])
        rho = data.radius[:, None] + data.radius[None, :]
        pm = _pair_ratios(data, rho)
        _draw_separation_curves(ax, data, rho, pm)
        ax.set_title(_separation_title(data, pm), loc="left")
        _draw_minimum_matrix(fig, axm, data.num_robots, pm)
        return save_png(fig, out / "separation.png")


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

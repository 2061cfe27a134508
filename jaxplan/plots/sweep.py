"""Heatmaps of a sweep directory over its (q_obs, q_lim) grid (:func:`plot_sweep`); the
numbers come from :mod:`jaxplan.sweep.table`."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib import colors as mcolors
from matplotlib.collections import LineCollection
from matplotlib.patches import Rectangle

from jaxplan.plots.style import FIGSIZE, STYLE, new_figure, save_png
from jaxplan.sweep.table import Grid, best_index, best_summary, grid, read_sweep_rows


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
    (:func:`jaxplan.sweep.table.best_setting`) is outlined in black on every panel.

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
        with matplotlib.rc_context({**STYLE, "axes.grid": False}):
            w, h = FIGSIZE["sweep_panel"]
            fig = new_figure((w * len(grids), h))
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
            out.append(save_png(fig, sweep_dir / "figures" / fname))
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

"""Figures of a tune directory (:func:`plot_tune`): the objective over trials, the
weights' importance, and the success / makespan Pareto front.  The numbers come from
:mod:`jaxplan.tune`."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from jaxplan.plots.style import FIGSIZE, STYLE, new_figure, save_png

_FEASIBLE = "#1b9e77"
_INFEASIBLE = "#d95f02"
_BEST = "#7570b3"


def _check(trials: list[dict]) -> None:
    for i, t in enumerate(trials):
        for k in ("number", "value", "feasible", "success_rate"):
            if k not in t:
                raise ValueError(f"trials[{i}]: {k}: missing")
        if not math.isfinite(float(t["value"])):
            raise ValueError(f"trials[{i}]: value: not finite ({t['value']})")


def pareto_front(success: np.ndarray, makespan: np.ndarray) -> np.ndarray:
    """Indices of the points no other point beats (success rate higher or equal and
    makespan lower or equal, one of them strictly), by increasing makespan."""
    idx = []
    for i in range(len(success)):
        beaten = np.any((success >= success[i]) & (makespan <= makespan[i])
                        & ((success > success[i]) | (makespan < makespan[i])))
        if not beaten:
            idx.append(i)
    return np.array(sorted(idx, key=lambda i: makespan[i]), int)


def plot_tune(fig_dir, trials: list[dict], importance: dict[str, float] | None, *,
              objective: str = "median_makespan_s") -> list[Path]:
    """Draw a study's figures into ``fig_dir``.

    trials: the complete trials, each {number, value, feasible, success_rate,
    ``objective`` (s), ...}.  importance: {weight: importance} (None: too few trials;
    the figure says so).  Writes objective.png (each trial's objective, infeasible ones
    apart, and the best so far), importance.png (a bar per weight) and pareto.png
    (success rate against ``objective``, the Pareto front joined).  Infeasible trials
    beyond the feasible ones' range are drawn on objective.png's top edge.  Raises ValueError on
    a trial without those keys or with a non-finite value.
    """
    import matplotlib

    _check(trials)
    out = Path(fig_dir)
    out.mkdir(parents=True, exist_ok=True)
    n = np.array([t["number"] for t in trials], int)
    value = np.array([t["value"] for t in trials], float)
    feas = np.array([bool(t["feasible"]) for t in trials], bool)
    succ = np.array([t["success_rate"] for t in trials], float)
    span = np.array([t.get(objective, np.nan) for t in trials], float)
    order = np.argsort(n)
    paths = []
    size = FIGSIZE["sweep_panel"]
    with matplotlib.rc_context(STYLE):
        fig = new_figure((size[0] * 1.4, size[1]))
        ax = fig.add_subplot()
        # infeasible trials (their value holds the penalty) drawn on the top edge, so
        # that the feasible ones' differences stay readable
        top = None
        if feas.any():
            lo, hi = value[feas].min(), value[feas].max()
            top = hi + 0.15 * max(hi - lo, 0.05 * abs(hi), 1e-3)
        shown = value if top is None else np.minimum(value, top)
        ax.scatter(n[feas], value[feas], s=18, color=_FEASIBLE, label="feasible")
        ax.scatter(n[~feas], shown[~feas], s=18, color=_INFEASIBLE, marker="x",
                   label="infeasible" + (" (off the scale, on the top edge)"
                                         if top is not None else " (value + penalty)"))
        if len(n):
            best = np.minimum.accumulate(shown[order])
            ax.step(n[order], best, where="post", color=_BEST, label="best so far")
        if top is not None:
            ax.set_ylim(top=top * 1.01 if top > 0 else top + 1e-3)
        ax.set_xlabel("trial")
        ax.set_ylabel(f"{objective} [s]")
        ax.set_title("objective over trials")
        if len(n):
            fig.legend(loc="outside lower center", ncols=3)
        paths.append(save_png(fig, out / "objective.png"))

        fig = new_figure(size)
        ax = fig.add_subplot()
        if importance:
            names = list(importance)[::-1]
            ax.barh(names, [importance[k] for k in names], color=_BEST)
            ax.set_xlabel("importance (PED-ANOVA, Optuna)")
        else:
            ax.text(0.5, 0.5, "too few trials to rank the weights", ha="center",
                    va="center", transform=ax.transAxes)
            ax.set_axis_off()
        ax.set_title("weights' importance")
        paths.append(save_png(fig, out / "importance.png"))

        fig = new_figure(size)
        ax = fig.add_subplot()
        ok = np.isfinite(span)
        ax.scatter(span[ok & feas], succ[ok & feas], s=18, color=_FEASIBLE, label="feasible")
        ax.scatter(span[ok & ~feas], succ[ok & ~feas], s=18, color=_INFEASIBLE, marker="x",
                   label="infeasible")
        idx = np.flatnonzero(ok)
        if idx.size:
            front = idx[pareto_front(succ[idx], span[idx])]
            ax.plot(span[front], succ[front], "-o", color=_BEST, ms=4, label="Pareto front")
            ax.legend(loc="lower right")
        ax.set_xlabel(f"{objective} [s] (a failed run counts as the duration)")
        ax.set_ylabel("success rate")
        ax.set_title("success / makespan")
        paths.append(save_png(fig, out / "pareto.png"))
    return paths

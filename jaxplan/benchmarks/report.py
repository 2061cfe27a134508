"""The benchmarks' figures as a markdown page (docs/BENCHMARKS.md, written by `make bench`).

    markdown(results, *, machine, commit, date) -> str
    write_markdown(path, results)     the same, with this machine, commit and date

``results`` is what `jaxplan bench all --json FILE` writes (``{"predict": ...,
"solver": ..., "sim": ...}``; any of them may be missing); each present benchmark gets a
table of its main figures with the reference measured in the same run.  One header
line names the command, the machine, the commit and the date.
"""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
from pathlib import Path

from jaxplan.fileio import atomic_write_text

__all__ = ["markdown", "write_markdown"]

COMMAND = "make bench (jaxplan bench all --json bench.json --markdown docs/BENCHMARKS.md)"


def _ms(x) -> str:
    return f"{x:.1f} ms" if x >= 10 else f"{x:.2f} ms"


def _pct(x) -> str:
    return f"{100 * x:.0f}%"


def _table(rows) -> list[str]:
    out = ["| measure | measured | reference / target |", "|---|---|---|"]
    out += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    return out


def _predict(r: dict) -> list[str]:
    return ["## Prediction (`jaxplan bench predict`)", "",
            f"{r['pairs']:,} (state, goal) pairs, jitted, float64.", "", *_table([
                ("closed-form predictions per second",
                 f"{r['predictions_per_s']:,.0f} ({r['threads']} threads); "
                 f"{r['predictions_per_s_single_thread']:,.0f} (one thread)",
                 f"target {r['target_predictions_per_s']:,}"),
                ("against a NumPy loop using numpy.roots",
                 f"{r['speedup_vs_numpy_roots']:,.0f}x "
                 f"({r['numpy_roots_predictions_per_s']:,.0f} /s)", "same run"),
                ("largest relative difference in T",
                 f"{r['max_rel_T_difference_vs_numpy_roots']:.1e}", "numpy.roots"),
                ("compile", f"{r['compile_s']:.1f} s", ""),
            ]), ""]


def _solver(r: dict) -> list[str]:
    f10, sc, sw = r["fleet10"], r["slsqp10_cold"], r["slsqp10_warm"]
    rows = [
        ("10-robot fleet replan, cold (initial guesses included)",
         f"{_ms(f10['cold_ms'])}, {_pct(f10['cold_conv'])} converged, "
         f"compile {f10['compile_s']:.1f} s",
         f"NLopt SLSQP serially: {_ms(sc['ms'])} ({r['ratio_cold']:.1f}x; "
         f"callbacks {_ms(sc['callback_ms'])})"),
        ("10-robot fleet replan, warm (median)",
         f"{_ms(f10['warm_ms'])}, {_pct(f10['warm_conv'])} converged",
         f"SLSQP: {_ms(sw['ms'])} ({r['ratio_warm']:.1f}x); target <= 10 ms"),
        ("objective gap (JAX - SLSQP) / max(1, SLSQP)",
         f"cold max {sc['rel_gap_max']:.1e}, warm max {sw['rel_gap_max']:.1e}",
         f"violation JAX {sc['jax_max_violation']:.1e}, SLSQP {sc['max_violation']:.1e}"),
    ]
    for key, what in (("fleet100", "100-robot fleet replan, every other robot"),
                      ("fleet100_k", f"100-robot fleet replan, {r.get('neighbors_k')} nearest "
                                     "others")):
        if key in r:
            f = r[key]
            rows.append((what, f"cold {_ms(f['cold_ms'])}, warm {_ms(f['warm_ms'])} "
                               f"({_pct(f['warm_conv'])} converged)", "target <= 300 ms"))
    if "batch64x10" in r:
        b = r["batch64x10"]
        lo, hi = b["solves_per_s_range"]
        rows.append(("64 scenarios x 10 robots, one cold batch",
                     f"{_ms(b['ms'])}: {b['solves_per_s']:,.0f} robot-NLP solves/s "
                     f"(timed calls {lo:,.0f}-{hi:,.0f}/s), {_pct(b['converged'])} converged",
                     f"{b['ratio_vs_slsqp_serial']:.0f}x serial SLSQP; target >= 5,000/s"))
    return ["## Solver (`jaxplan bench solver`)", "",
            "The paper's NLP (one quintic per axis + T, barrier + constraint collisions), "
            "antipodal fleets, free ends; SLSQP on the identical NLPs from the same starts.",
            "", *_table(rows), ""]


def _sim(r: dict) -> list[str]:
    rows = [("real-time factor, the 30 s closed loop (planning included)",
             f"{r['closed_loop_rtf']:.1f}x (compile {r['closed_loop_compile_s']:.0f} s)",
             "target >= 5x")]
    if "closed_loop_rtf_transit" in r:
        rows.append(("real-time factor, the first seconds (every robot flying)",
                     f"{r['closed_loop_rtf_transit']:.1f}x", ""))
    if "mjx_physics_only_steps_per_s" in r:
        rows.append(("one world, physics only", f"MJX {r['mjx_physics_only_steps_per_s']:,.0f} "
                     "steps/s", f"MuJoCo C mj_step {r['c_mj_step_steps_per_s']:,.0f} "
                     f"({r['ratio_mjx_physics_only_vs_c_mj_step']:.2f}x)"))
    key = next((k for k in r if k.startswith("world_cost_slowdown_ground_")), None)
    if key is not None:
        world = key.removeprefix("world_cost_slowdown_")   # "ground_20"
        note = ""
        if "world_cost_physics_steps_per_s_colliding" in r:
            note = (f"as colliding MuJoCo geoms instead: MJX physics "
                    f"{r['world_cost_physics_steps_per_s_colliding']:,.0f} steps/s, without "
                    f"{r['world_cost_physics_steps_per_s_none']:,.0f} (one vehicle)")
        rows.append((f"one world (in scan), the ground and {world.split('_')[1]} obstacles "
                     "measured every physics step",
                     f"{r['world_cost_rtf_in_scan_' + world]:.1f}x real time, "
                     f"{r[key]:.2f}x the time without a world", note))
    return ["## Closed loop (`jaxplan bench sim`)", "",
            f"{r['vehicles']} vehicles in MJX: physics {r['physics_hz']} Hz, control "
            f"{r['control_hz']} Hz, the planner at 8 Hz.", "", *_table(rows), ""]


def markdown(results: dict, *, machine: str, commit: str, date: str) -> str:
    """The page: one header line (command, machine, commit, date), then a section per
    benchmark present in ``results``."""
    lines = ["# Benchmarks", "", f"`{COMMAND}`; {machine}; commit {commit}; {date}.", "",
             "Medians over repeats; compile time apart from run time; every reference is "
             "measured in the same run. Wall times on a shared machine vary from run to run.",
             ""]
    for name, section in (("predict", _predict), ("solver", _solver), ("sim", _sim)):
        if name in results:
            lines += section(results[name])
    return "\n".join(lines)


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            cpu = next(ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{os.cpu_count()}-core CPU ({cpu})"


def _commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, cwd=Path(__file__).resolve().parent, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() or "unknown"


def write_markdown(path, results: dict) -> Path:
    """Write :func:`markdown` of ``results`` to ``path`` (atomically), naming this
    machine, the checkout's commit and today's date (UTC)."""
    date = datetime.datetime.now(datetime.UTC).date().isoformat()
    text = markdown(results, machine=_machine(), commit=_commit(), date=date)
    atomic_write_text(Path(path), text + "\n")
    return Path(path)

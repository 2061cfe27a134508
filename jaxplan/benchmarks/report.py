"""The benchmarks' figures as a markdown page (docs/BENCHMARKS.md, written by `make bench`).

    markdown(results, *, machine, commit, date) -> str
    write_markdown(path, results)     the same, with this machine, commit and date
    write_readme(path, results)       README's block after README_MARK: a header line (no
                                      commit: the page's names it) and
                                      the product table's main rows (the page's rows)

``results`` is what `jaxplan bench all --json FILE` writes (``{"predict": ...,
"solver": ..., "sim": ...}``; any of them may be missing); each present benchmark gets a
table of its main figures with the reference measured in the same run.  One header
line names the command, the machine, the commit and the date.
"""

from __future__ import annotations

import datetime
import subprocess
from pathlib import Path

import numpy as np

from jaxplan.files import atomic_write_text

__all__ = ["markdown", "readme_lines", "replace_readme_block", "write_markdown", "write_readme"]

COMMAND = ("make bench (jaxplan bench all --json bench.json --markdown docs/BENCHMARKS.md "
           "--readme README.md)")


def _ms(x) -> str:
    return f"{x:.1f} ms" if x >= 10 else f"{x:.2f} ms"


def _rounds(f: dict, key: str) -> str:
    """`` (rounds a / b / c)``: the figure ``key`` in each round of its timings
    (benchmarks.solver_fleets._rounds), where the JSON has them."""
    r = f.get(f"{key}_rounds")
    if not r or len(r) < 2:
        return ""
    return " (rounds " + " / ".join(_ms(x).removesuffix(" ms") for x in r) + ")"


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
    return [*_product(r), "## Solver, more figures (`jaxplan bench solver`)", "",
            "The paper's NLP (one quintic per axis + T, barrier + constraint collisions), "
            "antipodal fleets, free ends; SLSQP on the identical NLPs from the same starts; "
            "the whole machine (JAX on its CPU devices, SLSQP serially).",
            "", *_table(rows), ""]


def _verdict(ok: bool, why: str = "") -> str:
    return "met" if ok else f"**not met**{': ' + why if why else ''}"


def _gap_why(*refs) -> str:
    """Which side ended lower, and by how much, in the pairs beyond 1e-6."""
    lo = min(x["rel_gap_min"] for x in refs)
    hi = max(x["rel_gap_max"] for x in refs)
    why = []
    if lo < -1e-6:
        why.append(f"JAX ended lower by up to {-lo:.1e}")
    if hi > 1e-6:
        why.append(f"JAX ended higher by up to {hi:.1e}")
    return "; ".join(why)


def _product_table(r: dict) -> tuple[list[str], dict[str, str]]:
    """The product / paper NLP against IPOPT (CasADi) and SLSQP, with the issue's
    targets: (the table's two header lines, its rows by key in order)."""
    kinds = [k for k in ("product", "paper") if k in r]
    head = "| measure | " + " | ".join(f"{k} NLP" for k in kinds) + " | target (product NLP) |"
    rows: dict[str, str] = {}
    pr = r["product"]
    f, ip, sq = pr["fleet10"], pr["ipopt10"], pr["slsqp10"]
    load = pr.get("loadavg_1min")
    key = iter(["n_x", "warm", "cold", "ipopt", "slsqp", "slsqp_cold", "gap", "violation",
                "whole_machine"])

    def row(what, fn, target=""):
        rows[next(key)] = (f"| {what} | " + " | ".join(fn(r[k]) for k in kinds)
                           + f" | {target} |")

    row("variables n_x (segments, coast samples, static rows)",
        lambda x: f"{x['nlp']['n_x']} ({x['nlp']['segments']}, {x['nlp']['n_coast_samples']}, "
                  f"{x['nlp'].get('n_static', 0)})")
    row("JAX, 10-robot replan, warm (median of the replans' medians)",
        lambda x: f"{_ms(x['fleet10']['warm_ms'])}{_rounds(x['fleet10'], 'warm_ms')}, "
                  f"{_pct(x['fleet10']['warm_conv'])} converged, "
                  f"<= {x['fleet10']['warm_iters_max']} iterations",
        "<= 5 ms: " + _verdict(f["warm_ms"] <= 5.0, _warm_why(f, load)))
    row("JAX, cold (initial guesses included) / warm",
        lambda x: f"{_ms(x['fleet10']['cold_ms'])}{_rounds(x['fleet10'], 'cold_ms')} "
                  f"({x['cold_over_warm']:.2f}x warm)",
        "cold <= 2x warm: " + _verdict(pr["cold_over_warm"] <= 2.0,
                                       f"{pr['cold_over_warm']:.2f}x"))
    row("IPOPT (CasADi, SX derivatives), 10 NLPs one after another, warm / cold",
        lambda x: f"{_ms(x['ipopt10']['warm_ms'])} / {_ms(x['ipopt10']['cold_ms'])}: "
                  f"JAX {x['ratio_vs_ipopt_warm']:.1f}x / {x['ratio_vs_ipopt_cold']:.1f}x faster",
        ">= 10x warm: " + _verdict(pr["ratio_vs_ipopt_warm"] >= 10,
                                   f"{pr['ratio_vs_ipopt_warm']:.1f}x"))
    row("NLopt SLSQP, warm: total / callbacks taken out",
        lambda x: f"{_ms(x['slsqp10']['warm_ms'])} / {_ms(x['slsqp10']['warm_algorithm_ms'])}: "
                  f"JAX {x['ratio_vs_slsqp_warm']:.1f}x / "
                  f"{x['ratio_vs_slsqp_algorithm_warm']:.1f}x faster",
        ">= 10x without callbacks: " + _verdict(
            pr["ratio_vs_slsqp_algorithm_warm"] >= 10,
            f"{pr['ratio_vs_slsqp_algorithm_warm']:.1f}x: SLSQP's own work is "
            f"{sq['warm_algorithm_ms'] / 10:.1f} ms per NLP (median "
            f"{sq['iterations_or_evals_median']:.0f} evaluations), JAX's "
            f"{f['warm_ms'] / 10:.2f} ms"))
    row("NLopt SLSQP, cold: total / callbacks taken out",
        lambda x: f"{_ms(x['slsqp10']['cold_ms'])} / {_ms(x['slsqp10']['cold_algorithm_ms'])}: "
                  f"{x['ratio_vs_slsqp_cold']:.1f}x / {x['ratio_vs_slsqp_algorithm_cold']:.1f}x")
    gap_ok = max(ip["abs_rel_gap_max"], sq["abs_rel_gap_max"]) <= 1e-6
    viol_ok = ip["jax_max_violation"] <= max(ip["ref_max_violation"], sq["ref_max_violation"],
                                             1e-8)

    def gaps(x):
        a, b = x["ipopt10"], x["slsqp10"]
        return (f"IPOPT {a['rel_gap_min']:.1e} .. {a['rel_gap_max']:.1e} "
                f"({a['pairs_gap_over_1e6']} of {a['pairs']} beyond 1e-6); SLSQP "
                f"{b['rel_gap_min']:.1e} .. {b['rel_gap_max']:.1e} "
                f"({b['pairs_gap_over_1e6']} of {b['pairs']})")

    row("objective gap (JAX - ref) / max(1, abs(ref)), every pair (negative: JAX lower)", gaps,
        "abs(gap) <= 1e-6: " + _verdict(gap_ok, _gap_why(ip, sq)))
    row("largest violation (m^2): JAX / IPOPT / SLSQP",
        lambda x: f"{x['ipopt10']['jax_max_violation']:.1e} / "
                  f"{x['ipopt10']['ref_max_violation']:.1e} / "
                  f"{x['slsqp10']['ref_max_violation']:.1e}",
        "no worse: " + _verdict(viol_ok))
    if not all("whole_machine" in r[k] for k in kinds):
        next(key)
    else:
        row("the whole machine: JAX warm; ratios to IPOPT / SLSQP without callbacks",
            lambda x: f"{_ms(x['whole_machine']['fleet10']['warm_ms'])}; "
                      f"{x['whole_machine']['ratio_vs_ipopt_warm']:.1f}x / "
                      f"{x['whole_machine']['ratio_vs_slsqp_algorithm_warm']:.1f}x "
                      f"(references on {x['whole_machine']['workers']} processes)")
    if "fleet100" in pr:
        g = pr["fleet100"]
        rows["fleet100"] = (
            f"| 100 robots, every other robot in every NLP, warm (whole machine) | "
            f"{_ms(g['warm_ms'])}{_rounds(g, 'warm_ms')}, {_pct(g['warm_conv'])} converged; "
            "iterations per lane median "
            f"{g['warm_iters_median']:.0f}, max {g['warm_iters_max']}; "
            f"{g['warm_iters_sum_per_replan']:.0f} lane-iterations per replan at "
            f"{1e3 * g['warm_ms_per_lane_iteration']:.0f} us each |"
            + " |" * (len(kinds) - 1)
            + " <= 50 ms: " + _verdict(g["warm_ms"] <= 50.0, _fleet100_why(g)) + " |")
    if "obstacles20" in pr:
        rows["obstacles"] = _obstacles_row(pr["obstacles20"], len(kinds))
    return [head, "|---|" + "---|" * len(kinds) + "---|"], rows


def _split_why(t: dict) -> str:
    """Where a replan's time goes, from benchmarks.solver_split._time_split's accounting."""
    parts = []
    alone = "step_timed_alone" in t  # steps shared as timed alone (older files: derived)
    without = " without the others' terms" if alone else " without the others"
    if t["lockstep_steps"]:
        parts.append(f"{t['lockstep_steps']:g} steps of all {t['lanes_per_device']} lanes at "
                     f"{t['step_us_all_lanes']:.0f} us "
                     f"({t['step_us_all_lanes_without_others']:.0f} us{without})")
    if t["slot_steps"]:
        parts.append(f"{t['slot_steps']:g} steps of {t['pool']} slots at "
                     f"{t['step_us_pool']:.0f} us "
                     f"({t['step_us_pool_without_others']:.0f} us{without})")
    fixed = f"{_ms(t['fixed_ms'])} for the call's set-up and report"
    if "merit_ms" in t:  # the call allowed no iteration, less its evaluation of L_A per lane
        fixed += (f" (the call allowed no iteration, {_ms(t['no_iteration_ms'])}, less the "
                  f"evaluation of L_A per lane it makes for its report, {_ms(t['merit_ms'])} "
                  "timed alone)")
    else:
        fixed = (f"{_ms(t['fixed_ms'])} for the call without iterations (set-up, one "
                 "evaluation of L_A per lane, the report)")
    if alone:
        a = t["step_timed_alone"]
        fixed += (f"; the steps share the rest of the measured {_ms(t['measured_ms'])} as "
                  f"they cost timed alone (medians of {a['rounds']} interleaved calls of "
                  f"{a['steps_per_call']} steps, with and without the others' terms; "
                  f"x{a['scale']:.2f} of those timings)")
    parts.append(fixed)
    where = "the busier device: " if t["shards"] > 1 else ""
    return (f"{t['evaluations_per_replan']:.0f} evaluations per replan (per lane median "
            f"{t['evaluations_lane_median']:g}, max {t['evaluations_lane_max']}); {where}"
            + ", ".join(parts) + f"; a step without the {t['others_per_nlp']} other robots' "
            "terms is the NLP's own derivatives, its Newton step and the step's bookkeeping")


def _warm_why(f: dict, load) -> str:
    why = f"{_ms(f['warm_ms'])} on one core"
    if "time_split" in f:
        why += ": " + _split_why(f["time_split"])
    elif "warm_lane_iters_per_replan" in f:
        n = f["warm_lane_iters_per_replan"]
        why += (f": {n:.0f} lane-iterations per replan at {1e3 * f['warm_ms'] / n:.0f} us "
                "each")
    return why + (f" (load average {load:.1f})" if load else "")


def _fleet100_why(g: dict) -> str:
    if "time_split" in g:
        return f"{_ms(g['warm_ms'])}: " + _split_why(g["time_split"])
    return (f"{_ms(g['warm_ms'])}: {g['warm_iters_sum_per_replan']:.0f} lane-iterations per "
            f"replan (median {g['warm_iters_median']:.0f} per lane) at "
            f"{1e3 * g['warm_ms_per_lane_iteration']:.0f} us each, each lane's NLP holding "
            "the 99 others")


def _obstacles_row(o: dict, n_kinds: int) -> str:
    """The 10-robot warm replan with and without the obstacles (issue #32's row)."""
    w, n = o["with"], o["none"]
    per = lambda x: 1e3 * x["warm_ms"] / max(1.0, float(np.median(x["warm_iters_sum"])))
    its = lambda x: float(np.median(x["warm_iters_sum"]))
    rows = lambda x: (f"{x['n_static']} of {x['static_rows']}" if "static_rows" in x
                      else f"{x['n_static']}")
    why = (f"{o['warm_ratio']:.2f}x: lane-iterations per replan {its(w):.0f} vs {its(n):.0f}, "
           f"{per(w):.0f} vs {per(n):.0f} us each "
           f"({rows(w)} static rows per NLP vs {rows(n)})")
    return (f"| 10-robot warm fleet replan with {o['obstacles']} obstacles vs none (random_"
            f"obstacles world, arena walls and ceiling in both; whole machine) | "
            f"{_ms(w['warm_ms'])} vs {_ms(n['warm_ms'])}: {o['warm_ratio']:.2f}x, "
            f"{_pct(w['warm_conv'])} / {_pct(n['warm_conv'])} converged |"
            + " |" * (n_kinds - 1)
            + " <= 1.5x: " + _verdict(o["warm_ratio"] <= 1.5, why) + " |")


def _product(r: dict) -> list[str]:
    """The product / paper section of the page."""
    if "product" not in r:
        return []
    head, rows = _product_table(r)
    pr = r["product"]
    f, load = pr["fleet10"], pr.get("loadavg_1min")
    intro = ("The product's NLP is the one `jaxplan run` solves with the planner's defaults "
             "(2 quintic segments per axis, 8 coast samples, the default world's ground "
             "z >= 0 as a static row, the default weights, the safety margin, the planner's "
             "prediction and iteration cap: run_setup.structures and fleet_params); the "
             "paper's is 1 segment, no coast, no static row. A 10-robot antipodal fleet: the "
             "cold replan and "
             f"{pr.get('warm_replans', '')} warm replans (the planner's warm start), each "
             f"timed {pr.get('repeats', '')} times (medians)"
             + (", JAX's once in each of that many rounds minutes apart (before, between "
                "and after the references; the 100-robot fleet's before and after the "
                "10-robot comparisons and after its time split), each round's figure shown"
                if "warm_ms_rounds" in f else "")
             + "; IPOPT (CasADi, exact SX "
             "derivatives, MUMPS) and NLopt SLSQP (JAX callbacks) solve the same NLPs one "
             "after another from the same starts. One core against one core: a child "
             "process pinned to one CPU with one JAX device and one XLA thread "
             f"(CPU / wall of JAX's timed calls {f['cpu_per_wall']:.2f})"
             + (f"; 1-minute load average {load:.1f} on this machine during the run." if load
                else "."))
    return ["## Solver: the product's NLP against IPOPT and SLSQP (`jaxplan bench solver`)",
            "", intro, "", *head, *rows.values(), ""]


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


README_MARK = ("<!-- the header line and the table below are written by `make bench` "
               "(jaxplan bench --readme README.md): jaxplan/benchmarks/report.py -->")
README_ROWS = ("warm", "cold", "ipopt", "slsqp", "gap", "violation", "fleet100", "obstacles")


def readme_lines(results: dict, *, machine: str, commit: str, date: str) -> list[str]:
    """README's benchmark block: one header line (the command, machine, date and load;
    the commit is the page's), a blank line, the product table's main rows (each a row
    of the page)."""
    r = results["solver"]
    head, rows = _product_table(r)
    load = r["product"].get("loadavg_1min")
    # README holds no commit hash (tests/test_docs.py): the page's header line names it
    line = (f"`make bench`; {machine}; {date}"
            + (f"; 1-minute load average {load:.1f}" if load is not None else "")
            + ". The product's NLP against IPOPT and SLSQP, one core against one core; every "
              "figure, how it is measured and the commit: "
              "[docs/BENCHMARKS.md](docs/BENCHMARKS.md).")
    return [line, "", *head, *(rows[k] for k in README_ROWS if k in rows)]


def replace_readme_block(text: str, lines: list[str]) -> str:
    """``text`` with the block after :data:`README_MARK` (a header line, a blank line, a
    table) replaced by ``lines``."""
    old = text.split("\n")
    try:
        i = old.index(README_MARK)
    except ValueError:
        raise ValueError(f"no line {README_MARK!r} to write the benchmark table after") from None
    j = i + 3  # the header line, the blank line, then the table's lines
    while j < len(old) and old[j].startswith("|"):
        j += 1
    return "\n".join(old[:i + 1] + lines + old[j:])


def write_readme(path, results: dict) -> Path:
    """Rewrite README's benchmark block (:func:`readme_lines`) in ``path``."""
    date = datetime.datetime.now(datetime.UTC).date().isoformat()
    lines = readme_lines(results, machine=_machine(), commit=_commit(), date=date)
    p = Path(path)
    atomic_write_text(p, replace_readme_block(p.read_text(encoding="utf-8"), lines))
    return p


def _machine() -> str:
    from jaxplan.benchmarks.common import cpu_line

    return cpu_line()


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

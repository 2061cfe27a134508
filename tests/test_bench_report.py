"""jaxplan.benchmarks.report: bench.json -> docs/BENCHMARKS.md (no benchmark is run here:
the figures are made up, so that each can be found in the page)."""

from __future__ import annotations

import json

from jaxplan.benchmarks.report import (
    README_MARK,
    markdown,
    readme_lines,
    replace_readme_block,
    write_markdown,
)
from jaxplan.cli import main

PREDICT = {"pairs": 1_000_000, "threads": 2, "predictions_per_s": 2_471_234.0,
           "predictions_per_s_single_thread": 1_503_210.0, "target_predictions_per_s": 2_000_000,
           "speedup_vs_numpy_roots": 312.4, "numpy_roots_predictions_per_s": 7911.0,
           "max_rel_T_difference_vs_numpy_roots": 3.5e-15, "compile_s": 2.53}
FLEET = {"cold_ms": 2.13, "cold_conv": 1.0, "cold_iters": 6, "warm_ms": 1.41, "warm_conv": 1.0,
         "compile_s": 8.4}
SOLVER = {
    "fleet10": FLEET,
    "slsqp10_cold": {"ms": 82.1, "callback_ms": 62.4, "rel_gap_max": 5.2e-11,
                     "jax_max_violation": 0.0, "max_violation": 0.0},
    "slsqp10_warm": {"ms": 74.9, "rel_gap_max": 1.55e-11},
    "ratio_cold": 38.5, "ratio_warm": 53.1, "neighbors_k": 16,
    "fleet100": {"cold_ms": 258.5, "warm_ms": 45.3, "warm_conv": 1.0},
    "fleet100_k": {"cold_ms": 53.4, "warm_ms": 9.8, "warm_conv": 1.0},
    "batch64x10": {"ms": 43.4, "solves_per_s": 14741.0, "solves_per_s_range": [9799.0, 15012.0],
                   "converged": 1.0, "ratio_vs_slsqp_serial": 121.0},
}
SIM = {"vehicles": 10, "physics_hz": 500, "control_hz": 250, "closed_loop_rtf": 7.43,
       "closed_loop_compile_s": 40.2, "closed_loop_rtf_transit": 5.31,
       "mjx_physics_only_steps_per_s": 24400.0, "c_mj_step_steps_per_s": 98000.0,
       "ratio_mjx_physics_only_vs_c_mj_step": 0.249}


def test_every_benchmark_section_shows_its_figures():
    page = markdown({"predict": PREDICT, "solver": SOLVER, "sim": SIM},
                    machine="2-core CPU (test)", commit="abc1234", date="2026-12-04")
    lines = page.splitlines()
    header = [ln for ln in lines if "commit abc1234" in ln]
    assert header == ["`make bench (jaxplan bench all --json bench.json --markdown "
                      "docs/BENCHMARKS.md --readme README.md)`; 2-core CPU (test); commit "
                      "abc1234; 2026-12-04."]
    for figure in ("2,471,234", "312x", "3.5e-15", "2.13 ms", "38.5x", "1.41 ms", "53.1x",
                   "5.2e-11", "1.6e-11", "258.5 ms", "45.3 ms", "16 nearest", "9.80 ms",
                   "14,741 robot-NLP solves/s", "9,799-15,012/s", "121x", "7.4x", "5.3x",
                   "24,400", "98,000", "0.25x"):
        assert figure in page, figure
    assert page.count("## ") == 3


def test_world_cost_row():
    sim = {**SIM, "world_cost_rtf_in_scan_none": 33.0, "world_cost_rtf_in_scan_ground_20": 32.1,
           "world_cost_slowdown_ground_20": 1.028, "world_cost_slowdown_ground": 1.01,
           "world_cost_physics_steps_per_s_none": 31232.0,
           "world_cost_physics_steps_per_s_colliding": 3281.0}
    page = markdown({"sim": sim}, machine="m", commit="c", date="d")
    for figure in ("the ground and 20 obstacles", "32.1x real time", "1.03x the time",
                   "3,281 steps/s", "31,232"):
        assert figure in page, figure
    assert "obstacles" not in markdown({"sim": SIM}, machine="m", commit="c", date="d")


def test_missing_benchmarks_are_left_out():
    page = markdown({"solver": {k: v for k, v in SOLVER.items() if k != "fleet100_k"}},
                    machine="m", commit="c", date="d")
    assert "## Solver" in page and "## Prediction" not in page and "## Closed loop" not in page
    assert "nearest" not in page


def test_bench_command_takes_a_markdown_path(tmp_path, monkeypatch):
    import jaxplan.benchmarks.solver as bench_solver

    monkeypatch.setattr(bench_solver, "run", lambda: SOLVER)
    out, js = tmp_path / "BENCHMARKS.md", tmp_path / "bench.json"
    assert main(["bench", "solver", "--json", str(js), "--markdown", str(out)]) == 0
    page = out.read_text()
    assert page.startswith("# Benchmarks") and "14,741" in page
    assert json.loads(js.read_text())["batch64x10"]["ms"] == 43.4
    write_markdown(out, {"sim": SIM})  # overwritten whole
    assert "## Solver" not in out.read_text() and "7.4x" in out.read_text()


def _kind(warm_ms, ipopt_warm, algo_warm, gap_min, n_x):
    ref = lambda gmin: {"rel_gap_min": gmin, "rel_gap_max": 3e-11, "abs_rel_gap_max": abs(gmin),
                        "pairs_gap_over_1e6": int(abs(gmin) > 1e-6), "pairs": 50,
                        "jax_max_violation": 0.0, "ref_max_violation": 2e-9}
    return {
        "nlp": {"n_x": n_x, "segments": 2 if n_x == 16 else 1,
                "n_coast_samples": 8 if n_x == 16 else 0},
        "fleet10": {"cold_ms": 1.7 * warm_ms, "warm_ms": warm_ms, "warm_conv": 1.0,
                    "warm_iters_max": 9, "cpu_per_wall": 0.99, "warm_lane_iters_per_replan": 40},
        "ipopt10": {"cold_ms": 812.0, "warm_ms": ipopt_warm, **ref(gap_min)},
        "slsqp10": {"cold_ms": 900.0, "warm_ms": 777.0, "cold_algorithm_ms": 95.0,
                    "warm_algorithm_ms": algo_warm, "iterations_or_evals_median": 41.0,
                    **ref(-2e-12)},
        "ratio_vs_ipopt_warm": ipopt_warm / warm_ms, "ratio_vs_ipopt_cold": 812 / (1.7 * warm_ms),
        "ratio_vs_slsqp_warm": 777 / warm_ms, "ratio_vs_slsqp_cold": 900 / (1.7 * warm_ms),
        "ratio_vs_slsqp_algorithm_warm": algo_warm / warm_ms,
        "ratio_vs_slsqp_algorithm_cold": 95 / (1.7 * warm_ms), "cold_over_warm": 1.7,
        "repeats": 3, "warm_replans": 4, "loadavg_1min": 1.3,
        "whole_machine": {"fleet10": {"warm_ms": 0.8 * warm_ms}, "ratio_vs_ipopt_warm": 41.5,
                          "ratio_vs_slsqp_algorithm_warm": 6.25, "workers": 2},
    }


def test_the_product_table_states_each_target_and_why_it_is_missed():
    prod = _kind(6.4, 640.0, 48.0, -3.1e-5, 16)
    prod["fleet100"] = {"warm_ms": 61.0, "warm_conv": 1.0, "warm_iters_median": 4.0,
                        "warm_iters_max": 23, "warm_iters_sum_per_replan": 520.0,
                        "warm_ms_per_lane_iteration": 0.117}
    prod["obstacles20"] = {
        "obstacles": 20, "warm_ratio": 1.8, "repeats": 5, "warm_replans": 4,
        "with": {"n_static": 8, "static_rows": 26, "warm_ms": 9.0, "warm_conv": 1.0,
                 "warm_iters_sum": [30, 34]},
        "none": {"n_static": 6, "static_rows": 6, "warm_ms": 5.0, "warm_conv": 0.9,
                 "warm_iters_sum": [25, 25]}}
    paper = _kind(2.0, 300.0, 44.0, -1e-12, 7)

    def rendered():  # the page and its rows by their first cell
        page = markdown({"solver": {**SOLVER, "product": prod, "paper": paper}},
                        machine="m", commit="c", date="d")
        return page, {ln.split(" | ")[0]: ln for ln in page.splitlines() if ln.startswith("| ")}

    page, rows = rendered()
    warm = rows["| JAX, 10-robot replan, warm (median of the replans' medians)"]
    assert "6.40 ms" in warm and "2.00 ms" in warm
    assert ("<= 5 ms: **not met**: 6.40 ms on one core: 40 lane-iterations per replan at 160 us "
            "each (load average 1.3)") in warm
    assert "100.0x" in rows["| IPOPT (CasADi, SX derivatives), 10 NLPs one after another, "
                            "warm / cold"] and ">= 10x warm: met" in page
    slsqp = rows["| NLopt SLSQP, warm: total / callbacks taken out"]
    assert "7.5x" in slsqp and "**not met**: 7.5x: SLSQP's own work is 4.8 ms per NLP" in slsqp
    gap = rows["| objective gap (JAX - ref) / max(1, abs(ref)), every pair (negative: JAX lower)"]
    assert "1 of 50 beyond 1e-6" in gap and "JAX ended lower by up to 3.1e-05" in gap
    assert "cold <= 2x warm: met" in page and "no worse: met" in page
    big = rows["| 100 robots, every other robot in every NLP, warm (whole machine)"]
    assert "61.0 ms" in big and "median 4, max 23" in big and "117 us" in big
    assert "<= 50 ms: **not met**: 61.0 ms: 520 lane-iterations per replan" in big
    assert "41.5x / 6.2x (references on 2 processes)" in page
    # where the time goes, where the benchmark measured it (benchmarks.solver_split._time_split)
    prod["fleet10"]["time_split"] = dict(
        lanes_per_device=10, pool=2, shards=1, others_per_nlp=9, evaluations_per_replan=82,
        evaluations_lane_median=8.0, evaluations_lane_max=10, lockstep_steps=8, slot_steps=3,
        fixed_ms=1.27, no_iteration_ms=1.61, merit_ms=0.34, step_us_all_lanes=776.2,
        step_us_pool=433.4, step_us_pool_without_others=333.1,
        step_us_all_lanes_without_others=579.7, measured_ms=8.78)
    prod["fleet100"]["time_split"] = dict(
        lanes_per_device=50, pool=2, shards=2, others_per_nlp=99, evaluations_per_replan=322,
        evaluations_lane_median=3.0, evaluations_lane_max=4, lockstep_steps=0, slot_steps=81,
        fixed_ms=12.87, step_us_all_lanes=0.0, step_us_pool=654.6,
        step_us_pool_without_others=200.6, step_us_all_lanes_without_others=0.0,
        measured_ms=65.9)
    page, rows = rendered()
    assert ("<= 5 ms: **not met**: 6.40 ms on one core: 82 evaluations per replan (per lane "
            "median 8, max 10); 8 steps of all 10 lanes at 776 us (580 us without the others), "
            "3 steps of 2 slots at 433 us (333 us without the others), 1.27 ms for the call's "
            "set-up and report (the call allowed no iteration, 1.61 ms, less the evaluation of "
            "L_A per lane it makes for its report, 0.34 ms timed alone); a step "
            "without the 9 other robots' terms is the NLP's own derivatives, its Newton step "
            "and the step's bookkeeping (load average 1.3)") in rows[
        "| JAX, 10-robot replan, warm (median of the replans' medians)"]
    big = rows["| 100 robots, every other robot in every NLP, warm (whole machine)"]
    assert ("<= 50 ms: **not met**: 61.0 ms: 322 evaluations per replan (per lane median 3, "
            "max 4); the busier device: 81 steps of 2 slots at 655 us (201 us without the "
            "others), 12.9 ms for the call without iterations") in big  # an older JSON
    assert "lockstep" not in big and "steps of all" not in big  # no lockstep in that batch
    # each step's cost timed alone, the accounted time against the measured one
    prod["fleet10"]["time_split"].update(
        step_us_all_lanes=570.0, step_us_all_lanes_without_others=319.0, step_us_pool=289.0,
        step_us_pool_without_others=195.0,
        step_timed_alone=dict(steps_per_call=8, rounds=15, scale=0.83, us={}))
    page, rows = rendered()
    assert ("82 evaluations per replan (per lane median 8, max 10); 8 steps of all 10 lanes "
            "at 570 us (319 us without the others' terms), 3 steps of 2 slots at 289 us (195 "
            "us without the others' terms), 1.27 ms for the call's set-up and report (the call "
            "allowed no iteration, 1.61 ms, less the evaluation of L_A per lane it makes for "
            "its report, 0.34 ms timed alone); the steps share the rest of the measured 8.78 "
            "ms as they cost timed alone (medians of 15 interleaved calls of 8 steps, with and "
            "without the others' terms; x0.83 of those timings); a step without the 9 other "
            "robots' terms") in rows[
        "| JAX, 10-robot replan, warm (median of the replans' medians)"]
    del prod["fleet10"]["time_split"], prod["fleet100"]["time_split"]
    obs = rows["| 10-robot warm fleet replan with 20 obstacles vs none (random_obstacles world, "
               "arena walls and ceiling in both; whole machine)"]
    assert "9.00 ms vs 5.00 ms: 1.80x, 100% / 90% converged" in obs
    assert ("<= 1.5x: **not met**: 1.80x: lane-iterations per replan 32 vs 25, 281 vs 200 us "
            "each (8 of 26 static rows per NLP vs 6 of 6)") in obs
    prod["obstacles20"]["warm_ratio"] = 1.4
    page, _ = rendered()
    assert "<= 1.5x: met |" in page
    # README's block: a header line naming machine, commit and date, then rows of the page
    block = readme_lines({"solver": {**SOLVER, "product": prod, "paper": paper}},
                         machine="2-core CPU (x)", commit="c0ffee1", date="2026-12-04")
    assert block[0].startswith("`make bench`; 2-core CPU (x); 2026-12-04; "
                               "1-minute load average 1.3.") and block[1] == ""
    assert "c0ffee1" not in block[0]  # README holds no commit hash
    assert len(block) == 2 + 2 + 8 and all(ln in page.splitlines() for ln in block[4:])
    text = "\n".join(["# x", README_MARK, "old header", "", "| a |", "|---|", "| 1 |", "",
                      "## next"])
    new = replace_readme_block(text, block).split("\n")
    assert new[:2] == ["# x", README_MARK] and new[2:2 + len(block)] == block
    assert new[2 + len(block):] == ["", "## next"]


def test_the_readme_benchmark_table_is_the_generated_one():
    """README's benchmark block is what `make bench` (jaxplan bench --readme) wrote: the
    line after its marker names the command, machine and date (the commit: the page's
    header line), and every row of the table under it is a line of docs/BENCHMARKS.md,
    written by the same run."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    readme = (root / "README.md").read_text().splitlines()
    page = (root / "docs" / "BENCHMARKS.md").read_text()
    i = readme.index(README_MARK)
    m = re.match(r"`make bench`; (.+); (\d{4}-\d{2}-\d{2}); ", readme[i + 1])
    assert m  # the machine and the date; the page's header line (below) names the commit
    header = page.splitlines()[2]
    assert f"; {m.group(1)}; commit " in header and header.endswith(f"; {m.group(2)}.")
    rows = []
    for ln in readme[i + 3:]:
        if not ln.startswith("|"):
            break
        rows.append(ln)
    assert len(rows) >= 8
    assert [r for r in rows[2:] if r not in page.splitlines()] == []


def test_bench_command_rewrites_the_readme_block(tmp_path, monkeypatch):
    import jaxplan.benchmarks.solver as bench_solver

    res = {**SOLVER, "product": _kind(4.0, 640.0, 48.0, -1e-12, 16),
           "paper": _kind(2.0, 300.0, 44.0, -1e-12, 7)}
    monkeypatch.setattr(bench_solver, "run", lambda: res)
    readme = tmp_path / "README.md"
    readme.write_text("\n".join(["# r", README_MARK, "`make bench`: old", "", "| old |",
                                 "|---|", "", "## after"]) + "\n")
    assert main(["bench", "solver", "--readme", str(readme)]) == 0
    lines = readme.read_text().splitlines()
    assert lines[2].startswith("`make bench`; ") and "| old |" not in lines
    assert "<= 5 ms: met" in readme.read_text() and lines[-2:] == ["", "## after"]
    assert main(["bench", "predict", "--readme", str(readme)]) == 2


def test_the_targets_timings_are_the_median_of_rounds_minutes_apart():
    """benchmarks.solver_fleets._rounds: each case's figure is the median of its rounds of
    timings (a slow minute of the shared machine moves one round, not the figure); the
    page shows every round next to the figure."""
    from jaxplan.benchmarks.solver_fleets import _rounds

    cases = [{"ms": 9.0}, {"ms": 4.0}, {"ms": 5.0}, {"ms": 3.0}]
    rounds = _rounds(cases, [[6.0, 8.1, 5.2, 3.1], [6.5, 4.2, 9.9, 3.3]])
    assert [c["ms"] for c in cases] == [6.5, 4.2, 5.2, 3.1]
    assert cases[1]["ms_rounds"] == [4.0, 8.1, 4.2]
    assert rounds == {"cold_ms_rounds": [9.0, 6.0, 6.5], "warm_ms_rounds": [4.0, 5.2, 4.2]}
    prod = _kind(4.2, 640.0, 48.0, -1e-12, 16)
    prod["fleet10"].update(warm_ms_rounds=[4.0, 5.2, 4.2], cold_ms_rounds=[9.0, 6.0, 6.5])
    prod["fleet100"] = {"warm_ms": 47.0, "warm_conv": 1.0, "warm_iters_median": 2.0,
                        "warm_iters_max": 3, "warm_iters_sum_per_replan": 222.0,
                        "warm_ms_per_lane_iteration": 0.2, "warm_ms_rounds": [61.4, 33.5, 47.0]}
    page = markdown({"solver": {**SOLVER, "product": prod,
                                "paper": _kind(2.0, 300.0, 44.0, -1e-12, 7)}},
                    machine="m", commit="c", date="d")
    assert "4.20 ms (rounds 4.00 / 5.20 / 4.20), 100% converged" in page
    assert "(rounds 9.00 / 6.00 / 6.50) (1.70x warm)" in page
    assert "47.0 ms (rounds 61.4 / 33.5 / 47.0), 100% converged" in page
    assert "JAX's once in each of that many rounds minutes apart" in page


def test_the_machine_line_names_the_vector_instructions(monkeypatch):
    """The benchmark pages' and the studies' machine line names the widest vector
    instructions (XLA compiles for them: speed and round-off differ between AVX-512 and
    AVX2 machines of one model name)."""
    from unittest import mock

    import jaxplan.benchmarks.common as common

    def line(flags):
        info = f"model name\t: AMD EPYC\nflags\t\t: fpu sse2 {flags}\n"
        with mock.patch.object(common, "open", mock.mock_open(read_data=info), create=True):
            return common.cpu_line()

    monkeypatch.setattr(common.os, "sched_getaffinity", lambda _: {0, 1})
    assert line("avx avx2 avx512f avx512dq") == "2-core CPU (AMD EPYC, AVX-512)"
    assert line("avx avx2") == "2-core CPU (AMD EPYC, AVX2)"
    assert line("avx") == "2-core CPU (AMD EPYC)"

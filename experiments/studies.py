"""The studies behind docs/RESULTS.md: sets of resumable runs and sweeps, and the page.

    python experiments/studies.py paper     [--out DIR] [--backends B ...] [--only NAME ...]
    python experiments/studies.py collision [--seeds N] [--out DIR] [--batch B] [--fleets F ...]
    python experiments/studies.py faults    [--seeds N] [--out DIR] [--batch B] [--fleets F ...]
    python experiments/studies.py worlds    [--seeds N] [--out DIR] [--batch B] [--only W ...]
    python experiments/studies.py deadlock  [--seeds N] [--out DIR] [--batch B] [--only CELL ...]
    python experiments/studies.py baselines [--seeds N] [--out DIR] [--methods M ...]
                                            [--only FLEET ...]
    python experiments/studies.py results   [--out DIR]        (rebuild the page, run nothing)
    ... collision|faults|deadlock|worlds|baselines --collect  (tabulate what --out holds)
    make studies                            (every study into sweeps/studies/, as the page says)

``paper``: the paper's four scenarios (experiments/paper/*.toml), each under the ideal
and the mjx backend, default settings, seed 0, one `jaxplan run ... --quiet
--no-figures` each (a run directory per cell under ``--out/paper/``; a cell whose
metrics.json exists is not run again).

``collision``: the four collision modes ("paper", "barrier", "constraint",
"barrier+constraint") x the two benchmark fleets (experiments/benchmarks/antipodal_10.toml
and random_box_20.toml), everything else at its default.

``faults``: the same two fleets under each fault of ``[faults]`` alone, at the default
planner settings: 20% message loss; 300 ms latency; sigma = 2 cm noise on the states the
robots receive; robot 0 freezing (silent) at t = 2 s.  "Success" excepts the frozen robot
(it cannot reach its goal); a collision with it still counts.

``worlds``: the world scenarios (experiments/worlds/*.toml: pillars, wall_gap,
low_ceiling, random_obstacles with 12 robots and 15 obstacles) at the default planner
settings: ``--seeds`` seeds each under the ideal backend (a sweep per world), and seed 0
under both backends through `jaxplan run` (the replan times, and the mjx contacts).

``deadlock``: stalls with and without their resolution (``[planner] deadlock =
"auto" | "off"``, jaxplan/planner/stall.py; "auto", the default, sidesteps at once in the
plane and after ``sidestep_wait_3d_s`` in 3-D; ``--resolutions sidestep`` adds the
sidestep without the 3-D wait) on the fleets of experiments/deadlock/
(planar antipodal circles of 4 to 24 ground robots, exactly symmetric and with a 2 deg
random angular offset; planar random transitions of 10 and 20; 3-D circles that start in
one horizontal plane), the two benchmark fleets, and the benchmark fleets with robot 0
frozen at t = 2 s.  ``--seeds N`` caps every cell's seeds (default: 10 per circle, 20
otherwise); ``--off-seeds N`` caps the "off" cells of the planar and 3-D plane fleets,
where "off" stalls for the whole run (the benchmark fleets' "off" rows, compared with
"auto" seed for seed, keep theirs: ``OFF_COMPARED``).  ``make studies`` runs
``deadlock --resolutions auto off --off-seeds 3``.

``baselines``: the paper's planner against the planners a reader would use instead, in
the same harness and on the same seeds: "krishnan" (the paper's planner, default
settings), "orca" (RVO2 through pyrvo; planar fleets only; agent radius the robot's plus
safety_margin_m, as the planner's), "orca, r = 0.3 m" (the same with the robot's radius
alone, as the issue that asked for the baselines measured ORCA), "orca3d" (RVO2-3D's
algorithm in JAX; no obstacles) and the ablations of the paper's prediction
("constant velocity": the others fly on at their current velocity; "static": they stay
where they are), on the deadlock study's fleets without faults and the four worlds; "n/a"
where a method does not apply.  The "krishnan" cells are the deadlock study's "auto" and
the worlds study's sweep directories (run once for both studies).  ``--seeds N`` caps the
other methods' seeds (default: the krishnan cell's).  "ms per replan or step": the runs'
wall time over their replans (ORCA: steps of ``orca_time_step_s``), simulation included,
one run at a time, where the cell ran whole in one call (else n/a).

Each (study, setting, fleet) cell of ``collision``, ``faults`` and ``deadlock`` is one
`jaxplan sweep` directory under ``--out``, so an interrupted study resumes where it
stopped.  Batches of one run are the default because on a CPU a vmapped batch runs
every lane for as many solver iterations as its slowest lane needs (20 antipodal runs:
127 s batched, about 90 s one after another, 2-core CPU).

``--collect`` tabulates the sweep and run directories already under ``--out`` as they
are, without running (a sweep directory refuses a config that has changed since its
rows were made, e.g. by a new ``[planner]`` key: the rows stay those of the code that
made them).

Every study prints its table (markdown) and writes it to ``--out/<study>.md``, with
``--out/<study>.meta.json`` (the command, the machine, the date) and the cells'
aggregates in ``--out/<study>.json``; then it rewrites ``--results`` (default
docs/RESULTS.md) from every ``<study>.md`` under ``--out`` (not after a run
with ``--only``, whose table holds only some cells).  ``results`` does only that
last step.  In the page, a study whose table is not under ``--out`` keeps the table it
had, and the hand-written notes between ``<!-- notes:STUDY -->`` and
``<!-- /notes:STUDY -->`` are kept as they are.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import re
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
REPO = ROOT.parent
RESULTS = REPO / "docs" / "RESULTS.md"
FLEETS = {"antipodal_10": ROOT / "benchmarks" / "antipodal_10.toml",
          "random_box_20": ROOT / "benchmarks" / "random_box_20.toml"}
PAPER = ("six_neos", "eight_fireflys_stacked", "eight_mixed_transitions", "ten_mixed_rest")
BACKENDS = ("ideal", "mjx")
COLLISION_MODES = ("paper", "barrier", "constraint", "barrier+constraint")
FAULTS = {
    "20% message loss": {"enabled": True, "message_loss": 0.2},
    "300 ms latency": {"enabled": True, "latency_s": 0.3},
    "2 cm state noise": {"enabled": True, "noise_sigma_m": 0.02},
    "one frozen robot": {"enabled": True, "frozen_robot": 0, "frozen_at_s": 2.0,
                         "frozen_mode": "silent"},
}
DEADLOCK = ROOT / "deadlock"
ANGLE_JITTER_DEG = 2.0
# (cell name, base config, [scenario] overrides, seeds, [faults] or None)
DEADLOCK_CELLS = [
    *[(f"planar circle {n}{' +jitter' if j else ''}", DEADLOCK / "circle_planar.toml",
       {"count": n, "angle_jitter_deg": ANGLE_JITTER_DEG if j else 0.0}, 10, None)
      for n in (4, 8, 12, 16, 24) for j in (False, True)],
    ("planar box 10", DEADLOCK / "box_planar.toml", {}, 20, None),
    ("planar box 20", DEADLOCK / "box_planar.toml",
     {"count": 20, "box": [[-4.0, -4.0], [4.0, 4.0]]}, 20, None),
    ("antipodal_10", FLEETS["antipodal_10"], {}, 20, None),
    ("random_box_20", FLEETS["random_box_20"], {}, 20, None),
    ("3-D plane circle 8", DEADLOCK / "circle_3d.toml", {"count": 8}, 10, None),
    ("3-D plane circle 16", DEADLOCK / "circle_3d.toml", {"count": 16}, 10, None),
    ("antipodal_10, robot 0 frozen", FLEETS["antipodal_10"], {}, 20, FAULTS["one frozen robot"]),
    ("random_box_20, robot 0 frozen", FLEETS["random_box_20"], {}, 20,
     FAULTS["one frozen robot"]),
]
# the deadlock cells whose "off" rows are compared with "auto" run for run: --off-seeds
# does not cap them (elsewhere "off" stalls for the whole run, a baseline of a few seeds)
OFF_COMPARED = ("antipodal_10", "random_box_20", "antipodal_10, robot 0 frozen",
                "random_box_20, robot 0 frozen")
RESOLUTIONS = ("off", "auto", "sidestep")
# the worlds study's; the baselines study compares the first four (the others hold robots
# that run no planner, which the baselines cannot leave alone)
WORLDS = ("pillars", "wall_gap", "low_ceiling", "random_obstacles", "intruder",
          "crossing_traffic")
BASELINE_WORLDS = WORLDS[:4]
STUDIES = ("paper", "collision", "faults", "deadlock", "worlds", "baselines")
# baselines: the methods compared ([planner] overrides) and the fleets: the deadlock
# study's fleets without faults, then the worlds.  The paper's planner's cells are the
# deadlock ("auto") and worlds studies' own sweep directories (run once for both).
BASELINE_METHODS = {
    "krishnan": {},
    "orca": {"method": "orca"},
    "orca, r = 0.3 m": {"method": "orca", "safety_margin_m": 0.0},
    "orca3d": {"method": "orca3d"},
    "constant velocity": {"prediction": "constant_velocity"},
    "static": {"prediction": "static"},
}
BASELINE_FLEETS = [c for c in DEADLOCK_CELLS if c[4] is None] + [
    (w, ROOT / "worlds" / f"{w}.toml", {}, 20, None) for w in BASELINE_WORLDS]

# The page: one section per study, in this order.
TITLES = {"paper": "The paper's four scenarios", "collision": "Collision modes",
          "faults": "Faults", "deadlock": "Stalls and the sidestep",
          "worlds": "Worlds with obstacles",
          "baselines": "Baselines: ORCA and ablations of the prediction"}
INTRO = """\
# Results

The studies' tables, written by `make studies` (experiments/studies.py) from the tables
it leaves in sweeps/studies/. `python experiments/studies.py results` rebuilds this page
from those tables without running anything. Each table's first line names the command
that produced it, the machine and the date; the notes under a table are written by hand
and kept when the page is rebuilt.

Success: every robot reached every waypoint and no pair's exact separation fell below
rho_ij = r_i + r_j. min d/rho: the smallest ratio of separation to rho_ij over all pairs,
all times and all runs of the row (below 1 is a collision). Definitions of every figure:
docs/DESIGN.md (metrics.json, sweep.csv).
"""
DEFAULT_NOTES = {
    "paper": "Separation is exact in continuous time from the executed polynomial pieces "
             "(ideal) and checked at every physics step (mjx); so is each body's clearance above "
             "the ground (z >= 0, the default 3-D workspace). Replan: wall time of one fleet "
             "replan (all robots), median / p95. Run: wall time after compilation.",
    "collision": "Seeds 0..N-1 per row; antipodal_10: 10 mixed Fireflys and Neos swap to the "
                 "antipodal points of a 4 m sphere; random_box_20: 20 robots, random starts "
                 "and goals in a box (30 s runs).",
    "faults": "Each fault of `[faults]` alone, default settings. Success excepts the frozen "
              "robot; a collision with it still counts.",
    "deadlock": "Each fleet without (`deadlock = \"off\"`: detection only) and with the "
                "sidestep (`\"auto\"`, the default: at once in the plane, after 4 s more "
                "of the stall in 3-D). Stalls: stall onsets over all runs; stalled: robot-"
                "seconds stalled; T/bound: makespan over max_i(D_i / v_max + v_max / a_max), "
                "median and max over the successful runs; peak speed: the largest of any run.",
    "worlds": "Success also requires no robot body inside an obstacle or outside the "
              "workspace (exact from the executed pieces under ideal; every physics step "
              "under mjx). Clearance: distance from a robot's centre to the obstacle's "
              "surface (or a workspace face) minus its radius, min over robots, time and "
              "runs. The worlds: jaxplan/scenarios/worlds.py; intruder (a drone that runs "
              "no planner crosses a swarm mid-swap; success counts the swarm, collisions "
              "every robot): jaxplan/scenarios/traffic.py; crossing_traffic (people, moving "
              "cylinders, cross a corridor; the robots see each one's position and "
              "velocity at every replan): jaxplan/scenarios/worlds.py.",
    "baselines": "Each method in the same harness on the same seeds: its executed motion "
                 "as pieces, the same exact metrics. krishnan: the paper's planner, default "
                 "settings (its cells are the deadlock study's \"auto\" and the worlds "
                 "study's). orca: RVO2 through pyrvo (planar only), agent radius the "
                 "robot's plus safety_margin_m (orca, r = 0.3 m: the robot's alone), the "
                 "velocity change clamped to a_max per 0.05 s step. orca3d: RVO2-3D's "
                 "algorithm in JAX (no obstacles). constant velocity / static: the paper's "
                 "planner predicting the others flying on at their current velocity / "
                 "staying put. T/bound: makespan over max_i(D_i / v_max + v_max / a_max), "
                 "median and max over the runs in which every robot arrived (a collision "
                 "or not: success counts those).",
}


def _slug(s: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in s).strip("_")


def machine() -> str:
    """One line naming this machine: CPU count, model and widest vector instructions
    (XLA compiles for them: the closed loops' round-off, and so a chaotic run's outcome,
    differs between an AVX-512 and an AVX2 machine of the same model name;
    :func:`jaxplan.benchmarks.common.cpu_line`), OS, JAX's default backend."""
    from jaxplan.benchmarks.common import cpu_line

    cpu = cpu_line()
    try:
        import jax

        backend = jax.default_backend()
        if backend != "cpu":
            dev = jax.devices()[0]
            cpu += f", {backend.upper()} {getattr(dev, 'device_kind', '')}".rstrip()
    except Exception:  # noqa: BLE001 - a backend that cannot be queried: the CPU line
        pass
    return f"{cpu}, {platform.system()} {platform.machine()}"


def _today() -> str:
    return datetime.datetime.now(datetime.UTC).date().isoformat()


# ---------------------------------------------------------------------------------------
# collision / faults: sweeps
# ---------------------------------------------------------------------------------------


COLLECT = False  # --collect: tabulate the sweep directories as they are, run nothing


def _cell(base: Path, seeds: int, out: Path, batch: int, *, planner=None, faults=None,
          scenario=None) -> dict:
    import tomllib

    from jaxplan.config import parse_config
    from jaxplan.sweep import read_sweep_csv, run_sweep

    doc = tomllib.loads(base.read_text())
    doc.setdefault("planner", {}).update(planner or {})
    doc.setdefault("scenario", {}).update(scenario or {})
    if faults:
        doc["faults"] = dict(faults)
    doc["sweep"] = {"seeds": {"start": 0, "num": seeds}}
    cfg = parse_config(doc, source=str(base))
    if COLLECT:  # the rows as an earlier run of the study left them (its code, its config)
        if not (out / "sweep.csv").exists():
            raise SystemExit(f"--collect: no {out / 'sweep.csv'}")
        res = argparse.Namespace(csv=out / "sweep.csv", run_s=None, compile_s=None)
    else:
        res = run_sweep(cfg, out, progress=sys.stderr.isatty(), batch_size=batch,
                        figures=False, echo=None)
        if res.ran and not res.skipped:  # the whole cell ran now: its run time is whole
            (out / "timing.json").write_text(json.dumps(
                {"run_s": res.run_s, "compile_s": res.compile_s, "batch": res.batch_size,
                 "runs": res.ran}) + "\n")
    rows, _ = read_sweep_csv(res.csv, older=COLLECT)
    num = lambda k: [float(r[k]) for r in rows if r[k] not in ("", "nan")]  # noqa: E731
    ms = num("makespan_s")
    total = lambda k: int(sum(num(k))) if rows and k in rows[0] else None  # noqa: E731
    low = lambda k: min(num(k), default=None) if rows and k in rows[0] else None  # noqa: E731
    ratio = num("makespan_over_bound")
    timing = (json.loads((out / "timing.json").read_text())
              if (out / "timing.json").exists() else None)
    replans = sum(num("replans"))
    return {
        # one run at a time: the runs' wall time per replan (or ORCA step), simulation in
        "ms_per_replan": (1e3 * timing["run_s"] / replans
                          if timing and timing["batch"] == 1 and replans else None),
        "obstacle_collisions_total": total("obstacle_collisions"),
        "workspace_violations_total": total("workspace_violations"),
        "min_obstacle_clearance_m": low("min_obstacle_clearance_m"),
        "min_workspace_clearance_m": low("min_workspace_clearance_m"),
        "stalls": int(sum(num("stalls"))),
        "stalled_s": sum(num("stalled_s")),
        "parked": int(sum(num("parked"))),
        "over_bound_median": statistics.median(ratio) if ratio else None,
        "over_bound_max": max(ratio) if ratio else None,
        "peak_speed_ratio_max": max(num("peak_speed_ratio"), default=math.nan),
        "runs": len(rows),
        "success_rate": statistics.fmean(num("success")),
        "collisions_total": int(sum(num("collisions"))),
        "runs_with_collisions": sum(1 for r in rows if float(r["collisions"]) > 0),
        "min_separation_ratio": min(num("min_separation_ratio"), default=math.nan),
        "makespan_median_s": statistics.median(ms) if ms else None,
        "errors": sum(1 for r in rows if r.get("error")),
        "run_s": res.run_s, "compile_s": res.compile_s,
    }


def _sweep_study(a) -> tuple[str, dict]:
    if a.study == "collision":
        settings = {m: {"planner": {"collision": m}} for m in COLLISION_MODES}
        head = "collision mode"
    else:
        settings = {k: {"faults": v} for k, v in FAULTS.items()}
        head = "fault"
    if a.only:
        unknown = [k for k in a.only if k not in settings]
        if unknown:
            raise SystemExit(f"studies.py: error: --only {unknown[0]!r}: choose from "
                             f"{', '.join(repr(k) for k in settings)}")
        settings = {k: v for k, v in settings.items() if k in a.only}
    results = {}
    t0 = time.perf_counter()
    for name, kw in settings.items():
        for fleet in a.fleets:
            out = a.out / a.study / f"{_slug(name)}__{fleet}__{a.seeds}seeds"
            print(f"[{time.perf_counter() - t0:7.0f} s] {name} / {fleet} -> {out}", flush=True)
            results[f"{name} | {fleet}"] = _cell(FLEETS[fleet], a.seeds, out, a.batch, **kw)
    lines = [f"| {head} | fleet | runs | success | runs with collisions | colliding pairs "
             "| min d/rho | median makespan (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for key, r in results.items():
        name, fleet = key.split(" | ")
        mk = "n/a" if r["makespan_median_s"] is None else f"{r['makespan_median_s']:.2f}"
        shown = f"**{name}** (default)" if name == "barrier+constraint" else name
        lines.append(f"| {shown} | {fleet} | {r['runs']} | {100 * r['success_rate']:.0f}% | "
                     f"{r['runs_with_collisions']} | {r['collisions_total']} | "
                     f"{r['min_separation_ratio']:.3f} | {mk} |")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return "\n".join(lines), results


def _complete(out: Path, runs: int) -> bool:
    """The sweep directory ``out`` holds ``runs`` finished rows."""
    from jaxplan.sweep import read_sweep_csv

    return ((out / "sweep.csv").exists()
            and len(read_sweep_csv(out / "sweep.csv", older=True)[0]) >= runs)


def _deadlock_study(a) -> tuple[str, dict]:
    cells = DEADLOCK_CELLS
    if a.only:
        names = [c[0] for c in cells]
        unknown = [k for k in a.only if k not in names]
        if unknown:
            raise SystemExit(f"studies.py: error: --only {unknown[0]!r}: choose from "
                             f"{', '.join(repr(k) for k in names)}")
        cells = [c for c in cells if c[0] in a.only]
    results = {}
    t0 = time.perf_counter()
    for res in a.resolutions:  # the resolution first: its cells matter most
        for name, base, scenario, seeds, faults in cells:
            n = min(seeds, a.seeds) if a.seeds else seeds
            if res == "off" and a.off_seeds and name not in OFF_COMPARED:
                n = min(n, a.off_seeds)
            out = a.out / "deadlock" / f"{_slug(name)}__{res}__{n}seeds"
            if a.collect and not _complete(out, n):
                full = a.out / "deadlock" / f"{_slug(name)}__{res}__{seeds}seeds"
                if not _complete(full, seeds):
                    continue
                out, n = full, seeds
            print(f"[{time.perf_counter() - t0:7.0f} s] {name} / {res} -> {out}", flush=True)
            results[f"{name} | {res}"] = _cell(base, n, out, a.batch, scenario=scenario,
                                               planner={"deadlock": res}, faults=faults)
    f = lambda x, fmt="{:.2f}": "n/a" if x is None else fmt.format(x)  # noqa: E731
    lines = ["| fleet | resolution | runs | success | runs with collisions | min d/rho "
             "| median makespan (s) | T/bound median / max | stalls | stalled (s) | parked "
             "| peak speed / v_max |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    order = {c[0]: i for i, c in enumerate(DEADLOCK_CELLS)}
    keys = sorted(results, key=lambda k: (order[k.split(" | ")[0]], k.split(" | ")[1]))
    for key in keys:
        r = results[key]
        name, res = key.split(" | ")
        shown = f"**{res}**" if res == "auto" else res
        lines.append(f"| {name} | {shown} | {r['runs']} | {100 * r['success_rate']:.0f}% | "
                     f"{r['runs_with_collisions']} | {r['min_separation_ratio']:.3f} | "
                     f"{f(r['makespan_median_s'])} | {f(r['over_bound_median'])} / "
                     f"{f(r['over_bound_max'])} | {r['stalls']} | {r['stalled_s']:.0f} | "
                     f"{r['parked']} | {r['peak_speed_ratio_max']:.2f} |")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return "\n".join(lines), results


# ---------------------------------------------------------------------------------------
# paper: runs through the `jaxplan` command (run directories)
# ---------------------------------------------------------------------------------------


def _only(a, choices: tuple[str, ...]) -> tuple[str, ...]:
    """``choices`` restricted to ``--only`` (in their order); an unknown name exits."""
    if not a.only:
        return choices
    unknown = [k for k in a.only if k not in choices]
    if unknown:
        raise SystemExit(f"studies.py: error: --only {unknown[0]!r}: choose from "
                         f"{', '.join(choices)}")
    return tuple(n for n in choices if n in a.only)


def _paper_study(a) -> tuple[str, dict]:
    names = _only(a, PAPER)
    results = {}
    t0 = time.perf_counter()
    for name in names:
        for backend in a.backends:
            results[f"{name} | {backend}"] = _run_once(
                ROOT / "paper" / f"{name}.toml", a.out / "paper" / f"{name}__{backend}",
                backend, t0)
    f = lambda x, fmt="{:.3f}": "n/a" if x is None else fmt.format(x)  # noqa: E731
    lines = ["| scenario | backend | success | reached | collisions | ground contacts "
             "| min ground clearance (m) | min d/rho | makespan (s) "
             "| peak speed / v_max | replan ms (median / p95) | tracking cm (rms / max) "
             "| run (s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for key, m in results.items():
        name, backend = key.split(" | ")
        reached = sum(bool(r["reached"]) for r in m["per_robot"])
        s = m["solver"]
        tr = m.get("tracking")
        track = "-" if not tr else f"{100 * tr['rms_m']:.1f} / {100 * tr['max_m']:.1f}"
        label = f"{name} ({m['duration_s']:g} s)"
        lines.append(
            f"| {label} | {backend} | {'yes' if m['success'] else 'no'} | "
            f"{reached} / {m['robots']} | {m['collisions']} | "
            f"{f(m.get('workspace_violations'), '{}')} | "
            f"{f(m.get('min_workspace_clearance_m'))} | {f(m['min_separation_ratio'])} | "
            f"{f(m['makespan_s'], '{:.2f}')} | {f(m['peak_speed_over_limit'])} | "
            f"{f(s['median_ms'], '{:.1f}')} / {f(s['p95_ms'], '{:.1f}')} | {track} | "
            f"{f(m['run_s'], '{:.2f}')} |")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return "\n".join(lines), {k: {kk: m.get(kk) for kk in (
        "success", "collisions", "workspace_violations", "min_workspace_clearance_m",
        "min_separation_ratio", "makespan_s", "run_s", "compile_s")}
        for k, m in results.items()}


# ---------------------------------------------------------------------------------------
# worlds: a seed sweep per world (ideal), and seed 0 through `jaxplan run` on both backends
# ---------------------------------------------------------------------------------------


def _run_once(config: Path, out: Path, backend: str, t0: float) -> dict:
    mpath = out / "metrics.json"
    if COLLECT and not mpath.exists():
        raise SystemExit(f"--collect: no {mpath}")
    if not mpath.exists():  # metrics.json marks a complete run directory
        cmd = [sys.executable, "-m", "jaxplan", "run", str(config), "--out", str(out),
               "--backend", backend, "--quiet", "--no-figures"]
        print(f"[{time.perf_counter() - t0:7.0f} s] {config.stem} / {backend} -> {out}",
              flush=True)
        subprocess.run(cmd, check=True)
    return json.loads(mpath.read_text())


def _worlds_study(a) -> tuple[str, dict]:
    names = _only(a, WORLDS)
    t0 = time.perf_counter()
    results = {}
    f = lambda x, fmt="{:.3f}": "n/a" if x is None else fmt.format(x)  # noqa: E731
    lines = ["| world | backend | runs | success | collisions robot / obstacle / workspace "
             "| min d/rho | min clearance obstacle / workspace (m) | median makespan (s) "
             "| replan ms (median / p95, seed 0) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name in names:
        config = ROOT / "worlds" / f"{name}.toml"
        out = a.out / "worlds" / f"{name}__{a.seeds}seeds"
        print(f"[{time.perf_counter() - t0:7.0f} s] {name} / {a.seeds} seeds -> {out}", flush=True)
        cell = _cell(config, a.seeds, out, a.batch)
        runs = {b: _run_once(config, a.out / "worlds" / f"{name}__seed0__{b}", b, t0)
                for b in a.backends}
        results[name] = {"sweep": cell, "seed0": {b: {k: m.get(k) for k in (
            "success", "collisions", "obstacle_collisions", "workspace_violations",
            "min_separation_ratio", "min_obstacle_clearance_m", "min_workspace_clearance_m",
            "makespan_s", "solver")} for b, m in runs.items()}}
        if "ideal" in runs:
            s = runs["ideal"]["solver"]
            ms = f"{f(s['median_ms'], '{:.1f}')} / {f(s['p95_ms'], '{:.1f}')}"
        else:
            ms = "-"
        mk = f(cell["makespan_median_s"], "{:.2f}")
        lines.append(
            f"| {name} | ideal | {cell['runs']} | {100 * cell['success_rate']:.0f}% | "
            f"{cell['collisions_total']} / {f(cell['obstacle_collisions_total'], '{}')} / "
            f"{f(cell['workspace_violations_total'], '{}')} | "
            f"{f(cell['min_separation_ratio'])} | {f(cell['min_obstacle_clearance_m'])} / "
            f"{f(cell['min_workspace_clearance_m'])} | {mk} | {ms} |")
        if "mjx" in runs:
            m = runs["mjx"]
            s = m["solver"]
            lines.append(
                f"| {name} | mjx (seed 0) | 1 | {100 * float(m['success']):.0f}% | "
                f"{m['collisions']} / {f(m.get('obstacle_collisions'), '{}')} / "
                f"{f(m.get('workspace_violations'), '{}')} | {f(m['min_separation_ratio'])} | "
                f"{f(m.get('min_obstacle_clearance_m'))} / "
                f"{f(m.get('min_workspace_clearance_m'))} | {f(m['makespan_s'], '{:.2f}')} | "
                f"{f(s['median_ms'], '{:.1f}')} / {f(s['p95_ms'], '{:.1f}')} (mjx period) |")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return "\n".join(lines), results


def _baseline_cell(a, name: str, base: Path, scenario: dict, seeds: int, method: str):
    """One (fleet, method) cell of the baselines study: its results, or None where the
    method does not apply (RVO2 through pyrvo is planar-only; neither ORCA has obstacles
    in 3-D).  The paper's planner's cells are the deadlock and worlds studies' own."""
    world = name in WORLDS
    planar = "planar" in name
    if (method.startswith("orca,") or method == "orca") and not planar or (
            method == "orca3d" and world):
        return None
    planner = dict(BASELINE_METHODS[method])
    if method == "krishnan":
        out = (a.out / "worlds" / f"{name}__{seeds}seeds" if world
               else a.out / "deadlock" / f"{_slug(name)}__auto__{seeds}seeds")
    else:
        seeds = min(seeds, a.seeds) if a.seeds else seeds
        out = a.out / "baselines" / f"{_slug(name)}__{_slug(method)}__{seeds}seeds"
    if not world and not method.startswith("orca"):
        planner.setdefault("deadlock", "auto")  # as the deadlock study's "auto" cells
    if a.collect and not _complete(out, seeds):
        # tabulate the cell as a run with another --seeds left it: its most seeds
        stem = out.name.rsplit("__", 1)[0]
        found = sorted((int(m.group(1)), d) for d in out.parent.glob(f"{stem}__*seeds")
                       if (m := re.fullmatch(r".*__(\d+)seeds", d.name))
                       and _complete(d, int(m.group(1))))
        if not found:
            return None
        seeds, out = found[-1]
    return _cell(base, seeds, out, a.batch, scenario=scenario, planner=planner)


def _baselines_study(a) -> tuple[str, dict]:
    fleets = BASELINE_FLEETS
    if a.only:
        names = [c[0] for c in fleets]
        unknown = [k for k in a.only if k not in names]
        if unknown:
            raise SystemExit(f"studies.py: error: --only {unknown[0]!r}: choose from "
                             f"{', '.join(repr(k) for k in names)}")
        fleets = [c for c in fleets if c[0] in a.only]
    methods = a.methods or tuple(BASELINE_METHODS)
    results = {}
    t0 = time.perf_counter()
    for method in methods:
        for name, base, scenario, seeds, _ in fleets:
            print(f"[{time.perf_counter() - t0:7.0f} s] {name} / {method}", flush=True)
            results[f"{name} | {method}"] = _baseline_cell(a, name, base, scenario, seeds,
                                                           method)
    f = lambda x, fmt="{:.2f}": "n/a" if x is None else fmt.format(x)  # noqa: E731
    lines = ["| fleet | method | runs | success | runs with collisions | min d/rho "
             "| T/bound median / max | peak speed / v_max | stalls per run "
             "| ms per replan or step |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    order = {c[0]: i for i, c in enumerate(BASELINE_FLEETS)}
    rank = {m: i for i, m in enumerate(BASELINE_METHODS)}
    keys = sorted(results, key=lambda k: (order[k.split(" | ")[0]], rank[k.split(" | ")[1]]))
    for key in keys:
        r = results[key]
        name, method = key.split(" | ")
        shown = f"**{method}**" if method == "krishnan" else method
        if r is None:
            lines.append(f"| {name} | {shown} | - | n/a | n/a | n/a | n/a | n/a | n/a | n/a |")
            continue
        lines.append(f"| {name} | {shown} | {r['runs']} | {100 * r['success_rate']:.0f}% | "
                     f"{r['runs_with_collisions']} | {r['min_separation_ratio']:.3f} | "
                     f"{f(r['over_bound_median'])} / {f(r['over_bound_max'])} | "
                     f"{r['peak_speed_ratio_max']:.2f} | "
                     f"{r['stalls'] / max(1, r['runs']):.1f} | "
                     f"{f(r['ms_per_replan'], '{:.1f}')} |")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return "\n".join(lines), results


# ---------------------------------------------------------------------------------------
# docs/RESULTS.md
# ---------------------------------------------------------------------------------------


def _block(text: str, tag: str) -> str | None:
    """The text between ``<!-- tag -->`` and ``<!-- /tag -->`` in ``text`` (stripped)."""
    m = re.search(rf"<!-- {re.escape(tag)} -->\n(.*?)<!-- /{re.escape(tag)} -->", text, re.S)
    return m.group(1).strip() if m else None


def _table_from_out(out: Path, study: str) -> str | None:
    """The header line and table of ``study`` under ``out``, or None when it has none."""
    md = out / f"{study}.md"
    if not md.exists():
        return None
    table = md.read_text().strip()
    meta_path = out / f"{study}.meta.json"
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    command = meta.get("command", f"python experiments/studies.py {study}")
    host = meta.get("machine", "machine not recorded")
    date = meta.get("date") or datetime.datetime.fromtimestamp(
        md.stat().st_mtime, datetime.UTC).date().isoformat()
    return f"`{command}` (`make studies`); {host}; {date}.\n\n{table}"


def write_results(out: Path, path: Path = RESULTS) -> Path:
    """(Re)write the results page ``path`` from the tables under ``out``; the notes and the
    tables of studies that ``out`` lacks are kept from the page as it is."""
    old = path.read_text() if path.exists() else ""
    parts = [INTRO]
    for study in STUDIES:
        table = _table_from_out(out, study) or _block(old, f"table:{study}") or (
            f"Not measured yet: `python experiments/studies.py {study}`.")
        notes = _block(old, f"notes:{study}")
        if notes is None:
            notes = DEFAULT_NOTES[study]
        parts.append(f"## {TITLES[study]}\n\n<!-- table:{study} -->\n{table}\n"
                     f"<!-- /table:{study} -->\n\n<!-- notes:{study} -->\n{notes}\n"
                     f"<!-- /notes:{study} -->\n")
    text = "\n".join(parts)
    from jaxplan.files import atomic_write_text

    return atomic_write_text(path, text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study", choices=(*STUDIES, "results"),
                    help="a study to run, or 'results': rebuild --results from the tables "
                         "under --out without running anything")
    ap.add_argument("--seeds", type=int, default=None,
                    help="seeds per cell (default 20; deadlock: at most this many, default "
                         "each cell's own)")
    ap.add_argument("--out", type=Path, default=Path("sweeps/studies"),
                    help="where the cells and tables go (default sweeps/studies)")
    ap.add_argument("--batch", type=int, default=None,
                    help="runs per compiled batch (default: jaxplan.sweep's, one per CPU device)")
    ap.add_argument("--fleets", nargs="+", choices=tuple(FLEETS), default=tuple(FLEETS))
    ap.add_argument("--resolutions", nargs="+", choices=RESOLUTIONS,
                    default=("auto", "off"), help="deadlock: the resolutions to run")
    ap.add_argument("--off-seeds", type=int, default=None,
                    help="deadlock: at most this many seeds for the cells without the "
                         "resolution (the baseline) of the planar and 3-D plane fleets; "
                         "the benchmark fleets' (OFF_COMPARED) keep their seeds")
    ap.add_argument("--methods", nargs="+", choices=tuple(BASELINE_METHODS),
                    help="baselines: the methods to run (default all)")
    ap.add_argument("--collect", action="store_true",
                    help="collision, faults, deadlock, worlds: run nothing; tabulate the "
                         "sweep and run directories under --out as they are")
    ap.add_argument("--backends", nargs="+", choices=BACKENDS, default=BACKENDS,
                    help="paper, worlds: the backends to run (default both)")
    ap.add_argument("--only", nargs="+",
                    help="only these settings (collision modes, fault names, paper scenarios, "
                         "worlds, deadlock cells or baselines fleets)")
    ap.add_argument("--results", type=Path, default=RESULTS,
                    help="the results page to (re)write (default docs/RESULTS.md)")
    ap.add_argument("--no-results", action="store_true",
                    help="do not rewrite the results page after the study")
    a = ap.parse_args(argv)
    global COLLECT
    COLLECT = a.collect
    if a.study != "results":
        if a.study in ("collision", "faults", "worlds") and a.seeds is None:
            a.seeds = 20
        study = {"paper": _paper_study, "deadlock": _deadlock_study,
                 "worlds": _worlds_study, "baselines": _baselines_study}.get(a.study, _sweep_study)
        table, aggregates = study(a)
        print(table)
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / f"{a.study}.md").write_text(table + "\n")
        (a.out / f"{a.study}.json").write_text(json.dumps(aggregates, indent=1) + "\n")
        argv_shown = sys.argv[1:] if argv is None else list(argv)
        meta = {"command": shlex.join(["python", "experiments/studies.py", *argv_shown]),
                "machine": machine(), "date": _today()}
        (a.out / f"{a.study}.meta.json").write_text(json.dumps(meta, indent=1) + "\n")
        print(f"table in {a.out / (a.study + '.md')}")
    if a.study == "results" or not (a.no_results or a.only):
        print(f"wrote {write_results(a.out, a.results)}")
    elif a.only:  # a table of some cells only would replace the page's whole table
        print(f"{a.results} left as it is (--only: a partial table); "
              f"`python experiments/studies.py {a.study} --collect --out {a.out}` "
              "tabulates every cell there and rewrites it")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The `jaxplan` command line: argument parsing, the subcommands, the compilation cache
(docs/DESIGN.md, "The command").

    jaxplan run CONFIG.toml [--out DIR]        one experiment -> a run directory
    jaxplan sweep CONFIG.toml [--out DIR]      a grid of weights x scenarios x seeds
        [--engine local|ray [--address ADDR]] [--shard I/N | --merge]
    jaxplan rerun SWEEP_DIR ROW [--out DIR]    a sweep.csv row as a full run directory
    jaxplan tune CONFIG.toml [--trials N] [--out DIR]   weights searched by Optuna
    jaxplan plot RUN_DIR                        (re)draw a run's figures
    jaxplan export RUN_DIR --format crazyswarm|mcap [--out DIR] [--height M]
                                                flights for Crazyflies, a file for Foxglove
    jaxplan bench [solver|predict|sim|all] [--json FILE] [--markdown FILE]
    jaxplan scenarios                           list built-in scenarios

Bad input exits with status 2 and one line on stderr that names the problem.

`run` and `sweep` keep compiled XLA programs in JAX's persistent compilation cache
(:func:`compile_cache_dir`), so that a repeated run of the same config skips most of its
compile time; `--no-cache` (or ``JAXPLAN_CACHE_DIR=""``) turns that off.  That directory is
kept under :data:`CACHE_MAX_BYTES` (least recently used entries removed first; JAX's
``JAX_COMPILATION_CACHE_MAX_SIZE``, in bytes, overrides it).  `bench` does not turn it on
(its compile times are meant to be compiles).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

BENCHES = ("predict", "solver", "sim", "all")
CACHE_ENV = "JAXPLAN_CACHE_DIR"
CACHE_MAX_BYTES = 1 << 30  # jaxplan's own cache directory: 1 GiB (a run's entry is ~1-2 MB)
CACHE_MAX_ENV = "JAX_COMPILATION_CACHE_MAX_SIZE"  # JAX's own setting, in bytes (-1: no limit)
CACHE_ENTRY_SUFFIX = "-cache"  # file names JAX's size-bounded cache directory uses
CACHE_ATIME_SUFFIX = "-atime"


class _Fail(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="jaxplan",
        description="Batched decentralized continuous-time multi-robot trajectory "
        "optimization in JAX (Krishnan et al.).",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    r = sub.add_parser("run", help="run one experiment and write a run directory")
    r.add_argument("config", type=Path, help="experiment TOML file")
    r.add_argument("--out", type=Path, default=None,
                   help="run directory (default: runs/<name>)")
    r.add_argument("--backend", choices=("ideal", "mjx"), default=None,
                   help="override sim.backend of the config")
    r.add_argument("--no-figures", action="store_true", help="skip the figures")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--no-cache", action="store_true",
                   help="do not use the compilation cache (see JAXPLAN_CACHE_DIR)")
    s = sub.add_parser("sweep", help="run a weight x scenario x seed grid (resumable)")
    s.add_argument("config", type=Path, help="sweep TOML file (with a [sweep] table)")
    s.add_argument("--out", type=Path, default=None,
                   help="sweep directory (default: sweeps/<name>)")
    s.add_argument("--batch", type=int, default=None,
                   help="runs at a time (default: one per CPU device on a CPU, each its "
                        "own one-run program: the rows do not depend on it; 27 vmapped on a "
                        "GPU)")
    s.add_argument("--engine", choices=("local", "ray"), default=None,
                   help="where the batches run: this process (local) or Ray tasks (ray; "
                        "needs jaxplan[ray]); default: [sweep] engine, else local")
    s.add_argument("--address", default=None, metavar="ADDR",
                   help="with --engine ray: the Ray cluster to join (e.g. auto, HOST:6379); "
                        "default: a local Ray instance, one worker per core")
    part = s.add_mutually_exclusive_group()
    part.add_argument("--shard", type=_shard, default=None, metavar="I/N",
                      help="run only the grid points with index %% N == I, into "
                           "sweep.shard-I-of-N.csv (0 <= I < N)")
    part.add_argument("--merge", action="store_true",
                      help="merge the sweep directory's shard files into sweep.csv and "
                           "draw the figures (runs nothing)")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--no-cache", action="store_true",
                   help="do not use the compilation cache (see JAXPLAN_CACHE_DIR)")
    rr = sub.add_parser("rerun", help="re-run a sweep.csv row as a full run (its metrics "
                                      "bitwise the row's)")
    rr.add_argument("sweep_dir", type=Path, help="a sweep directory")
    rr.add_argument("row", type=int, help="the row's index in sweep.csv (0-based, the "
                                          "header not counted)")
    rr.add_argument("--out", type=Path, default=None,
                    help="run directory (default: SWEEP_DIR/runs/row-ROW)")
    rr.add_argument("--no-figures", action="store_true", help="skip the figures and animation")
    rr.add_argument("--no-cache", action="store_true",
                    help="do not use the compilation cache (see JAXPLAN_CACHE_DIR)")
    t = sub.add_parser("tune", help="search the [tune] weights for the objective (resumable)")
    t.add_argument("config", type=Path, help="TOML file with a [tune] table")
    t.add_argument("--trials", type=int, default=None,
                   help="complete trials wanted in all (default: [tune] trials)")
    t.add_argument("--out", type=Path, default=None,
                   help="tune directory (default: tunes/<name>)")
    t.add_argument("--batch", type=int, default=None,
                   help="runs at a time (default: one per CPU device on a CPU, each its "
                        "own program; 27 vmapped on an accelerator; or JAXPLAN_SWEEP_BATCH)")
    t.add_argument("--no-figures", action="store_true", help="skip the figures")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.add_argument("--no-cache", action="store_true",
                   help="do not use the compilation cache (see JAXPLAN_CACHE_DIR)")
    pl = sub.add_parser("plot", help="(re)draw a run directory's figures")
    pl.add_argument("run_dir", type=Path)
    pl.add_argument("--no-animation", action="store_true")
    b = sub.add_parser("bench", help="benchmarks (medians; compile time apart)")
    b.add_argument("which", nargs="?", default="all", choices=BENCHES)
    b.add_argument("--json", type=Path, default=None, help="write the figures as JSON")
    b.add_argument("--markdown", type=Path, default=None,
                   help="write the figures as a markdown page (docs/BENCHMARKS.md)")
    b.add_argument("--readme", type=Path, default=None,
                   help="rewrite this README's benchmark table (solver or all)")
    sub.add_parser("scenarios", help="list built-in scenarios")
    e = sub.add_parser("export", help="a run as Crazyswarm trajectories or an MCAP file "
                                      "(docs/HARDWARE.md)")
    e.add_argument("run_dir", type=Path)
    e.add_argument("--format", required=True, choices=("crazyswarm", "mcap"), dest="fmt",
                   help="crazyswarm: one uav_trajectory CSV per robot (at most 31 pieces, "
                        "within 1 cm); mcap: one .mcap file for Foxglove")
    e.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="output directory (default: RUN_DIR/crazyswarm; RUN_DIR for mcap)")
    e.add_argument("--height", type=float, default=None, metavar="M",
                   help="crazyswarm, planar runs only: the flight height in m (default 1.0)")
    return p


def _shard(text: str) -> tuple[int, int]:
    """--shard I/N -> (I, N); argparse reports a bad one (exit status 2)."""
    from jaxplan.sweep import parse_shard

    try:
        return parse_shard(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def compile_cache_dir() -> Path | None:
    """The directory `jaxplan run` and `jaxplan sweep` keep compiled programs in:
    ``$JAXPLAN_CACHE_DIR`` when set (empty: no cache), else
    ``$XDG_CACHE_HOME/jaxplan/xla`` (default ``~/.cache/jaxplan/xla``)."""
    env = os.environ.get(CACHE_ENV)
    if env is not None:
        return Path(env).expanduser() if env.strip() else None
    base = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(base) if base else Path.home() / ".cache") / "jaxplan" / "xla"


def _use_compile_cache(off: bool) -> str | None:
    """Point JAX's persistent compilation cache at :func:`compile_cache_dir` (before the
    first compile); return the directory in use, or None.  A directory already chosen
    through JAX (``JAX_COMPILATION_CACHE_DIR``, jax.config) is kept.  JAX keys each
    entry by the program, the JAX/XLA versions, the flags and the device, and caches
    only programs that took >= 1 s to compile.  jaxplan's directory is bounded to
    :data:`CACHE_MAX_BYTES` (JAX evicts the least recently used entries) unless
    ``JAX_COMPILATION_CACHE_MAX_SIZE`` is set.  ``off`` (--no-cache): no persistent
    cache at all, not even one chosen through JAX."""
    import jax

    if off:
        jax.config.update("jax_enable_compilation_cache", False)
        return None
    if jax.config.jax_compilation_cache_dir:
        return jax.config.jax_compilation_cache_dir
    d = compile_cache_dir()
    if d is None:
        return None
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # e.g. a read-only home: run without it
        print(f"jaxplan: note: no compilation cache ({d}: {e.strerror})", file=sys.stderr)
        return None
    if CACHE_MAX_ENV not in os.environ:
        jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)
    if jax.config.jax_compilation_cache_max_size != -1:
        _stamp_unstamped(d)
    jax.config.update("jax_compilation_cache_dir", str(d))
    return str(d)


def _stamp_unstamped(d: Path) -> None:
    """Give every entry of cache directory ``d`` that has no access-time file one (its
    modification time), so that JAX's size-bounded cache, which reads one per entry when
    it evicts, can manage entries written while no bound was set (e.g. under
    ``JAX_COMPILATION_CACHE_MAX_SIZE=-1``).

    JAX stores an entry as ``<key>-cache`` and its last access as ``<key>-atime`` (8 bytes,
    nanoseconds, little-endian): :data:`CACHE_ENTRY_SUFFIX`, :data:`CACHE_ATIME_SUFFIX`.
    """
    for entry in d.glob(f"*{CACHE_ENTRY_SUFFIX}"):
        stamp = d / (entry.name.removesuffix(CACHE_ENTRY_SUFFIX) + CACHE_ATIME_SUFFIX)
        if not stamp.exists():
            try:
                stamp.write_bytes(entry.stat().st_mtime_ns.to_bytes(8, "little"))
            except OSError:  # unreadable or vanished: JAX reports it if it matters
                pass


def _load(path: Path):
    from jaxplan.config import ConfigError, load_config

    try:
        return load_config(path)
    except ConfigError as e:
        raise _Fail(str(e)) from None
    except FileNotFoundError:
        raise _Fail(f"{path}: no such file") from None


def _cmd_run(args) -> int:
    cfg = _load(args.config)
    if args.backend:
        import dataclasses

        cfg = dataclasses.replace(cfg, sim=dataclasses.replace(cfg.sim, backend=args.backend))
        if args.backend == "mjx" and cfg.dim != 3:  # as the parser checks [sim] backend
            raise _Fail(f"{args.config}: --backend: 'mjx' simulates quadrotors and needs 3-D "
                        f"positions; this config is {cfg.dim}-D (use --backend ideal)")
    from jaxplan.experiment import run
    from jaxplan.files import write_run

    out = args.out or Path("runs") / cfg.name
    cache = _use_compile_cache(args.no_cache)
    res = run(cfg, progress=not args.quiet)
    write_run(res, out)
    if not args.no_figures:  # drawn from the files just written (as `jaxplan plot` does)
        from jaxplan.plots import plot_run

        plot_run(out)
    print(summary(res.metrics, out, cache))
    return 0


def summary(m: dict, out: Path, cache: str | None = None) -> str:
    """The one-screen summary printed at the end of `jaxplan run` (``cache``: the
    compilation cache directory in use, if any)."""
    f = lambda x, fmt="{:.3f}": "n/a" if x is None else fmt.format(x)
    s = m["solver"]
    coop = [r for r in m["per_robot"] if r.get("cooperative", True)]
    lines = [
        f"{m['name']}: {'SUCCESS' if m['success'] else 'FAILED'}  ({m['robots']} robots, "
        f"backend {m['backend']}, {m['replans']} replans over {m['duration_s']:.1f} s)",
        f"  collisions {m['collisions']}   min separation ratio "
        f"{f(m['min_separation_ratio'])} ({m.get('separation_source', 'exact, continuous time')}"
        "; < 1 is a collision)",
        f"  makespan {f(m['makespan_s'], '{:.2f}')} s   peak speed {f(m['peak_speed'], '{:.2f}')}"
        f" m/s ({f(m['peak_speed_over_limit'], '{:.3f}')} x v_max)",
        f"  reached {sum(r['reached'] for r in coop)}/{len(coop)} robots"
        + (f" (and {m['robots'] - len(coop)} non-cooperative)" if len(coop) < m["robots"] else "")
        + (f"; after reaching it, up to {m['max_goal_departure_m']:.2f} m from it"
           if m.get("max_goal_departure_m") is not None else "")
        + (f"; all settled by {m['settled_makespan_s']:.2f} s"
           if m.get("settled_makespan_s") is not None else ""),
        f"  peak / limit: speed {f(m.get('peak_speed_ratio'))}, acc "
        f"{f(m.get('peak_acc_ratio'))}, jerk {f(m.get('peak_jerk_ratio'))} (planned"
        + (f"; tracked: speed {f(m.get('tracked_peak_speed_ratio'))}, acc "
           f"{f(m.get('tracked_peak_acc_ratio'))}" if "tracked_peak_acc_ratio" in m else "")
        + f")   goal excursion {f(m.get('goal_excursion_m'), '{:.2f}')} m   escape "
        f"{f(m.get('escape_m'), '{:.2f}')} m",
        f"  replan wall time: median {f(s['median_ms'], '{:.1f}')} ms, p95 "
        f"{f(s['p95_ms'], '{:.1f}')} ms, max {f(s['max_ms'], '{:.1f}')} ms; "
        f"converged {f(s['converged_frac'], '{:.1%}')}",
        f"  fallbacks: kept previous plan {m['fallbacks']['kept_previous']}, "
        f"braking {m['fallbacks']['braking']}, best effort {m['fallbacks']['best_effort']}, "
        f"goal occupied {m['fallbacks'].get('goal_occupied', 0)}",
        f"  stalls {m.get('stalls', 0)} ({m.get('stalled_s', 0.0):.1f} robot-s stalled, "
        f"{m.get('sidestep_s', 0.0):.1f} robot-s sidestepping), parked {m.get('parked', 0)}, "
        f"makespan / bound {f(m.get('makespan_over_bound'), '{:.2f}')}",
        f"  compile {m['compile_s']:.1f} s, run {m['run_s']:.2f} s"
        + (f" (compilation cache: {cache})" if cache else ""),
        f"  results in {out}/ (metrics.json, trajectories.npz, config.toml, figures/)",
    ]
    tr = m.get("tracking")
    if tr:
        lines.insert(4, f"  tracking error: rms {100 * tr['rms_m']:.2f} cm, max "
                        f"{100 * tr['max_m']:.2f} cm (simulated vs planned position)")
    if "obstacle_collisions" in m:
        lines.insert(2, f"  obstacle contacts {m['obstacle_collisions']} (min clearance "
                        f"{f(m.get('min_obstacle_clearance_m'))} m)   workspace violations "
                        f"{m.get('workspace_violations', 0)} (min clearance "
                        f"{f(m.get('min_workspace_clearance_m'))} m)")
    return "\n".join(lines)


def _cmd_plot(args) -> int:
    from jaxplan.plots import plot_run

    if not args.run_dir.is_dir():
        raise _Fail(f"{args.run_dir}: not a directory")
    try:
        paths = plot_run(args.run_dir, animation=not args.no_animation)
    except ValueError as e:
        raise _Fail(str(e)) from None
    for p in paths:
        print(p)
    return 0


def _cmd_bench(args) -> int:
    which = ["predict", "solver", "sim"] if args.which == "all" else [args.which]
    if args.readme is not None and "solver" not in which:
        print("jaxplan bench: --readme needs the solver benchmark (solver or all)",
              file=sys.stderr)
        return 2
    results = {}
    for name in which:
        if name == "predict":
            from jaxplan.benchmarks.predict import run
        elif name == "solver":
            from jaxplan.benchmarks.solver import run
        else:
            from jaxplan.benchmarks.sim import run
        results[name] = run()
    if args.json:
        from jaxplan.benchmarks.common import write_json

        write_json(args.json, results if len(which) > 1 else results[which[0]])
        print(f"wrote {args.json}")
    if args.markdown:
        from jaxplan.benchmarks.report import write_markdown

        write_markdown(args.markdown, results)
        print(f"wrote {args.markdown}")
    if args.readme:
        from jaxplan.benchmarks.report import write_readme

        write_readme(args.readme, results)
        print(f"wrote the benchmark table in {args.readme}")
    return 0


def _cmd_export(args) -> int:
    from jaxplan.export import ExportError, export_run

    try:
        if args.fmt == "crazyswarm":
            from jaxplan.export.crazyswarm import table

            report = export_run(args.run_dir, "crazyswarm", args.out, height=args.height)
            print(table(report))
            if report["height_m"] is not None:
                print(f"planar run: flown at z = {report['height_m']:g} m; yaw 0")
            print(f"wrote {len(report['robots'])} CSVs and export.json in {report['out']}")
        else:
            report = export_run(args.run_dir, "mcap", args.out, height=args.height)
            print(f"wrote {report['file']} ({report['messages']} messages, "
                  f"{report['bytes'] / 1e6:.1f} MB)")
    except ExportError as e:
        raise _Fail(str(e)) from None
    return 0


def _cmd_scenarios(args) -> int:
    from jaxplan.scenarios import SCENARIOS

    width = max(len(n) for n in SCENARIOS)
    for name, spec in SCENARIOS.items():
        print(f"{name:<{width}}  {spec.description}")
    return 0


def _cmd_sweep(args) -> int:
    cfg = _load(args.config)
    from jaxplan.sweep import SweepError, merge_shards, run_sweep

    if args.batch is not None and args.batch < 1:
        raise _Fail(f"--batch must be >= 1, got {args.batch}")
    engine = args.engine or cfg.sweep.engine
    if args.address is not None and engine != "ray":
        raise _Fail(f"--address {args.address}: needs --engine ray (or [sweep] engine = "
                    '"ray")')
    if args.merge and (args.engine or args.address or args.batch):
        raise _Fail("--merge runs nothing: it takes no --engine, --address or --batch")
    out = args.out or Path("sweeps") / cfg.name
    try:
        if args.merge:
            merge_shards(cfg, out)
            return 0
        _use_compile_cache(args.no_cache)
        run_sweep(cfg, out, progress=not args.quiet, batch_size=args.batch, engine=engine,
                  address=args.address, shard=args.shard)
    except SweepError as e:
        raise _Fail(str(e)) from None
    return 0


def _cmd_rerun(args) -> int:
    from jaxplan.sweep import SweepError
    from jaxplan.sweep.rerun import rerun_row

    cache = _use_compile_cache(args.no_cache)
    try:
        res = rerun_row(args.sweep_dir, args.row, args.out, figures=not args.no_figures)
    except SweepError as e:
        raise _Fail(str(e)) from None
    print(summary(res.metrics, res.out, cache))
    return 0


def _cmd_tune(args) -> int:
    cfg = _load(args.config)
    from jaxplan.tune import TuneError, run_tune

    for flag, v in (("--trials", args.trials), ("--batch", args.batch)):
        if v is not None and v < 1:
            raise _Fail(f"{flag} must be >= 1, got {v}")
    if cfg.tune is None:
        raise _Fail(f"{args.config}: tune: missing; `jaxplan tune` needs a [tune] table "
                    "(docs/DESIGN.md)")
    out = args.out or Path("tunes") / cfg.name
    _use_compile_cache(args.no_cache)
    try:
        run_tune(cfg, out, trials=args.trials, progress=not args.quiet,
                 batch_size=args.batch, figures=not args.no_figures)
    except TuneError as e:
        raise _Fail(str(e)) from None
    return 0


def main(argv=None) -> int:
    """Entry point; returns the exit status."""
    args = _parser().parse_args(argv)
    import jaxplan  # (float64)

    if jaxplan.CPU_DEVICES_ERROR:
        print(f"jaxplan: error: {jaxplan.CPU_DEVICES_ERROR}", file=sys.stderr)
        return 2
    cmds = {"run": _cmd_run, "sweep": _cmd_sweep, "rerun": _cmd_rerun, "tune": _cmd_tune,
            "plot": _cmd_plot,
            "bench": _cmd_bench, "scenarios": _cmd_scenarios, "export": _cmd_export}
    try:
        return cmds[args.command](args)
    except _Fail as e:
        print(f"jaxplan: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jaxplan: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())

"""experiments/studies.py: the results page is rewritten from whole tables only."""

import importlib.util
from pathlib import Path

STUDIES = Path(__file__).resolve().parent.parent / "experiments" / "studies.py"


def _studies():
    spec = importlib.util.spec_from_file_location("studies", STUDIES)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_a_run_of_some_cells_leaves_the_results_page_alone(tmp_path, capsys):
    """With --only the study's table holds only those cells: the page keeps its own
    (a run of one cell replaced the page's whole stall table by that one row); a run
    of every cell rewrites it.  (--collect over an empty --out: nothing runs.)"""
    studies = _studies()
    page = tmp_path / "RESULTS.md"
    out = tmp_path / "out"
    args = ["deadlock", "--collect", "--out", str(out), "--results", str(page)]
    assert studies.main([*args, "--only", "antipodal_10"]) == 0
    assert not page.exists()
    assert "left as it is (--only" in capsys.readouterr().out
    assert (out / "deadlock.md").exists()  # the partial table, under --out only
    assert studies.main(args) == 0
    assert "<!-- table:deadlock -->" in page.read_text()


def test_off_seeds_caps_only_the_stalling_baselines(tmp_path, monkeypatch):
    """``--off-seeds`` caps the "off" cells of the planar and 3-D plane fleets, not the
    benchmark fleets' "off" rows (compared with "auto" seed for seed), and ``make
    studies`` runs the deadlock study so (the page's table is made by that command)."""
    studies = _studies()
    seen = {}

    def cell(base, n, out, batch, **kw):
        seen[out.name] = n
        return dict(runs=n, success_rate=1.0, runs_with_collisions=0, min_separation_ratio=1.0,
                    makespan_median_s=1.0, over_bound_median=1.0, over_bound_max=1.0, stalls=0,
                    stalled_s=0.0, parked=0, peak_speed_ratio_max=1.0)

    monkeypatch.setattr(studies, "_cell", cell)
    assert studies.main(["deadlock", "--resolutions", "auto", "off", "--off-seeds", "3",
                         "--out", str(tmp_path), "--no-results"]) == 0
    for name, _, _, seeds, _ in studies.DEADLOCK_CELLS:
        slug = studies._slug(name)
        off = seeds if name in studies.OFF_COMPARED else min(seeds, 3)
        assert seen[f"{slug}__auto__{seeds}seeds"] == seeds
        assert seen[f"{slug}__off__{off}seeds"] == off
    assert len(seen) == 2 * len(studies.DEADLOCK_CELLS)
    assert set(studies.OFF_COMPARED) <= {c[0] for c in studies.DEADLOCK_CELLS}
    make = (STUDIES.parent.parent / "Makefile").read_text()
    assert "studies.py deadlock --resolutions auto off --off-seeds 3" in make


def test_the_baselines_study_shares_the_planners_cells(tmp_path, monkeypatch):
    """The baselines study's "krishnan" cells are the deadlock ("auto") and worlds
    studies' sweep directories (with their configs: the same planner overrides), the
    other methods' its own; RVO2 through pyrvo is not run on a 3-D fleet nor RVO2-3D in
    a world with obstacles (their rows read n/a); ``make studies`` runs the study."""
    studies = _studies()
    seen = {}

    def cell(base, n, out, batch, *, planner=None, scenario=None, faults=None):
        seen[str(out.relative_to(tmp_path))] = (n, planner)
        return dict(runs=n, success_rate=1.0, runs_with_collisions=0, min_separation_ratio=1.0,
                    over_bound_median=1.0, over_bound_max=1.0, stalls=2 * n,
                    peak_speed_ratio_max=1.0, ms_per_replan=None)

    monkeypatch.setattr(studies, "_cell", cell)
    assert studies.main(["baselines", "--out", str(tmp_path), "--no-results",
                         "--seeds", "5"]) == 0
    fleets = studies.BASELINE_FLEETS
    assert seen["deadlock/planar_circle_24__auto__10seeds"] == (10, {"deadlock": "auto"})
    assert seen["worlds/pillars__20seeds"] == (20, {})
    assert seen["baselines/planar_box_20__static__5seeds"] == (
        5, {"prediction": "static", "deadlock": "auto"})
    assert seen["baselines/planar_box_10__orca__5seeds"] == (5, {"method": "orca"})
    assert "baselines/antipodal_10__orca__5seeds" not in seen
    assert "baselines/pillars__orca3d__5seeds" not in seen
    assert seen["baselines/antipodal_10__orca3d__5seeds"] == (5, {"method": "orca3d"})
    planar = sum("planar" in c[0] for c in fleets)
    worlds = len(studies.BASELINE_WORLDS)
    assert seen["baselines/planar_box_10__orca__r___0_3_m__5seeds"] == (
        5, {"method": "orca", "safety_margin_m": 0.0})
    assert len(seen) == 6 * len(fleets) - 2 * (len(fleets) - planar) - worlds
    table = (tmp_path / "baselines.md").read_text().splitlines()
    assert len(table) == 2 + 6 * len(fleets)
    assert "| antipodal_10 | orca | - | n/a |" in "\n".join(table)
    assert "| planar box 10 | **krishnan** | 20 | 100% | 0 | 1.000 | 1.00 / 1.00 | 1.00 | 2.0 |" \
        in table[2 + 6 * 10]
    make = (STUDIES.parent.parent / "Makefile").read_text()
    assert "studies.py baselines --out sweeps/studies" in make

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

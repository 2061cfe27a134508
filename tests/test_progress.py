"""Progress output: a tqdm bar on a terminal, plain lines (no carriage returns) in a log."""

import io

from jaxplan.progress import LineProgress, progress_bar


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_log_gets_plain_lines():
    buf = io.StringIO()
    bar = progress_bar(10, "demo", "run", stream=buf)
    assert isinstance(bar, LineProgress)
    bar._interval = 0.0  # every update writes a line
    for _ in range(4):
        bar.update(1)
    bar.n = 7
    bar.refresh()
    bar.close()
    bar.close()  # idempotent
    text = buf.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert lines[0].startswith("demo: 1/10 runs")
    assert "ETA" in lines[0]
    assert lines[-1].startswith("demo: 7/10 runs")
    assert len(lines) == 6


def test_lines_are_rate_limited():
    buf = io.StringIO()
    bar = LineProgress(1000, "demo", "replan", file=buf, interval_s=3600.0)
    for _ in range(1000):
        bar.update()
    assert buf.getvalue() == ""  # nothing until the interval passes ...
    bar.close()
    assert buf.getvalue().splitlines() == [buf.getvalue().strip()]  # ... or the end
    assert "1000/1000" in buf.getvalue() and "ETA" not in buf.getvalue()


def test_terminal_gets_tqdm():
    bar = progress_bar(5, "demo", "run", initial=2, stream=_Tty())
    assert not isinstance(bar, LineProgress)
    assert bar.n == 2
    bar.close()


def test_a_bar_opened_after_the_compile_leaves_it_out_of_the_eta(monkeypatch):
    """AfterFirstUpdate (jaxplan run's and jaxplan tune's bar): nothing before the first
    update; the units of that update (which held the compile) are the bar's initial
    count, outside its rate, so the ETA is that of the work after it."""
    import jaxplan.progress as pr

    clock = [0.0]
    monkeypatch.setattr(pr.time, "perf_counter", lambda: clock[0])
    buf = io.StringIO()
    bar = pr.AfterFirstUpdate(100, "demo", "replan", stream=buf)
    clock[0] = 60.0  # a minute of compiling, then the first replan
    bar.set(1)
    assert buf.getvalue() == ""
    clock[0] = 100.0  # 40 s for 10 more replans: 4 s each, 89 to go
    bar.set(11)
    bar.bar._interval = 0.0
    bar.bar.refresh()
    line = buf.getvalue().splitlines()[-1]
    assert line == "demo: 11/100 replans, 40 s, ETA 356 s", line
    bar.close()
    # by whole batches (tune): the first batch opens the bar, the next ones count
    buf = io.StringIO()
    bar = pr.AfterFirstUpdate(12, "demo", "run", stream=buf)
    clock[0] = 200.0
    bar.update(3)
    clock[0] = 230.0
    bar.update(3)
    bar.close()
    assert buf.getvalue().splitlines()[-1] == "demo: 6/12 runs, 30 s, ETA 60 s"
    quiet = pr.AfterFirstUpdate(5, "demo", "run", stream=io.StringIO())
    quiet.close()  # never opened: nothing, no error
    assert quiet.bar is None


def test_a_bar_started_after_the_compile_counts_from_its_initial(monkeypatch):
    """The sweep's use: start() right after the compile, at the runs a resumed sweep
    skipped; every batch then counts in the rate."""
    import jaxplan.progress as pr

    clock = [0.0]
    monkeypatch.setattr(pr.time, "perf_counter", lambda: clock[0])
    buf = io.StringIO()
    bar = pr.AfterFirstUpdate(10, "demo", "run", initial=4, stream=buf)
    clock[0] = 50.0  # compiled
    bar.start()
    clock[0] = 60.0
    bar.update(2)
    bar.close()
    assert buf.getvalue().splitlines()[-1] == "demo: 6/10 runs, 10 s, ETA 20 s"
    off = pr.NoProgress()
    off.start(), off.update(3), off.set(5), off.close()

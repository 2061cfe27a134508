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

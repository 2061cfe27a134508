"""Progress over long work: a tqdm bar on a terminal, plain lines in a log.

tqdm redraws its bar with carriage returns, which in a file (CI logs, ``nohup``,
``> run.log``) becomes one ever-growing line.  When stderr is not a terminal,
:func:`progress_bar` returns :class:`LineProgress` instead: one line at most every
``LINE_INTERVAL_S`` seconds (and at the end) with the count, elapsed time and ETA.
:class:`AfterFirstUpdate` opens either only when the work reports its first unit, so
that a compile before it does not enter the rate and the ETA.
"""

from __future__ import annotations

import sys
import time

LINE_INTERVAL_S = 30.0


class LineProgress:
    """The part of tqdm's interface jaxplan uses (``n``, update, refresh, close)."""

    def __init__(self, total: int, desc: str, unit: str, initial: int = 0, file=None,
                 interval_s: float = LINE_INTERVAL_S):
        self.total, self.desc, self.unit = int(total), desc, unit
        self.n = self._start = int(initial)
        self._file = file if file is not None else sys.stderr
        self._interval = interval_s
        self._t0 = self._last = time.perf_counter()
        self._closed = False

    def update(self, k: int = 1) -> None:
        self.n += int(k)
        self.refresh()

    def refresh(self) -> None:
        now = time.perf_counter()
        if now - self._last >= self._interval:
            self._write(now)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._write(time.perf_counter())

    def _write(self, now: float) -> None:
        self._last = now
        el = now - self._t0
        done = self.n - self._start
        left = self.total - self.n
        eta = f", ETA {el / done * left:.0f} s" if done > 0 and left > 0 else ""
        print(f"{self.desc}: {self.n}/{self.total} {self.unit}s, {el:.0f} s{eta}",
              file=self._file, flush=True)


def progress_bar(total: int, desc: str, unit: str, initial: int = 0, leave: bool = True,
                 stream=None):
    """A tqdm bar when ``stream`` (default stderr) is a terminal, else a LineProgress."""
    stream = stream if stream is not None else sys.stderr
    if getattr(stream, "isatty", lambda: False)():
        from tqdm.auto import tqdm

        return tqdm(total=total, initial=initial, unit=unit, desc=desc, leave=leave,
                    dynamic_ncols=True, smoothing=0.0, file=stream)
    return LineProgress(total, desc, unit, initial, file=stream)


class AfterFirstUpdate:
    """A :func:`progress_bar` opened after the compile, not before: work that starts by
    compiling (tens of seconds) counts only its own time in the rate and the ETA (a bar
    opened before the compile put it in: `jaxplan run`'s first line said "1/320 replans,
    38 s, ETA 12038 s").  ``start()`` opens it (at ``initial``, e.g. runs a resumed sweep
    skips) where the caller knows the compile has ended; otherwise the first
    ``update(k)`` / ``set(n)`` opens it, the units of that update (which held the
    compile) as its initial count, outside its rate.  Nothing is shown before."""

    def __init__(self, total: int, desc: str, unit: str, initial: int = 0,
                 leave: bool = True, stream=None):
        self._args = (total, desc, unit)
        self._initial, self._leave, self._stream = int(initial), leave, stream
        self.bar = None

    def _open(self, initial: int) -> bool:
        """Open the bar at ``initial`` if it is not open; whether it was."""
        if self.bar is not None:
            return True
        self.bar = progress_bar(*self._args, initial=int(initial), leave=self._leave,
                                stream=self._stream)
        return False

    def start(self) -> None:
        self._open(self._initial)

    def update(self, k: int = 1) -> None:
        if self._open(self._initial + k):
            self.bar.update(k)

    def set(self, n: int) -> None:
        if self._open(n):
            self.bar.n = int(n)
            self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class NoProgress:
    """AfterFirstUpdate's interface, showing nothing (progress off)."""

    def start(self) -> None:
        pass

    def update(self, k: int = 1) -> None:
        pass

    def set(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass

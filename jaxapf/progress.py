"""Progress of a long run, on a terminal or in a log.

On a terminal a tqdm bar; where stderr is a file or a pipe (nohup, Slurm, CI), where a bar would be
switched off and the log stay empty, one plain line at the first update, then at most every
``every`` seconds and at the end: done/total, rate and the time left.
"""

from __future__ import annotations

import re
import sys
import time
from typing import Any, TextIO

from .text import format_seconds

__all__ = ["Progress", "PROGRESS_LINE", "without_progress"]

#: A line :class:`Progress` writes to a log (what a reader of the log can tell apart from the rest).
PROGRESS_LINE = re.compile(r"^.+: [\d,]+/[\d,]+ \S+ \(\d+ %\), [\d,.]+ \S+/s, .+$")


def without_progress(text: str) -> str:
    """``text`` (a run's stderr) without the progress lines: what the run said besides how far it was."""
    return "\n".join(line for line in text.splitlines() if not PROGRESS_LINE.match(line))


class Progress:
    """``update(n)`` as work is done, ``close()`` at the end (also as a context manager)."""

    def __init__(self, total: int, desc: str, unit: str, *, quiet: bool = False, initial: int = 0,
                 every: float = 30.0, stream: TextIO | None = None):
        self.total, self.desc, self.unit, self.every = total, desc, unit, every
        self.done = self.start_done = initial
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.bar: Any = None
        self.start = self.last = time.monotonic()
        self.said: int | None = None  # what the last line said was done
        self.postfix: dict[str, str] = {}
        if not quiet and self.stream.isatty():
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, unit_scale=unit == "ep",
                            dynamic_ncols=True, file=self.stream)

    def update(self, n: int) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.update(n)
            return
        now = time.monotonic()
        if not self.quiet and (self.said is None or now - self.last >= self.every):
            self._say(now)

    def set_postfix(self, **fields: str) -> None:
        """Figures shown after the progress (the bar's postfix; the end of the log's line)."""
        self.postfix = fields
        if self.bar is not None:
            self.bar.set_postfix(**fields)

    def line(self, now: float) -> str:
        """``NAME: done/total unit (share), rate unit/s, time left`` as the log shows it."""
        spent = now - self.start
        rate = (self.done - self.start_done) / spent if spent > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        share = 100.0 * self.done / self.total if self.total else 100.0
        ending = ("done in " + format_seconds(spent)) if self.done >= self.total else (
            f"{format_seconds(left)} left" if left == left else "time left unknown")
        extra = "".join(f", {k} {v}" for k, v in self.postfix.items())
        return (f"{self.desc}: {self.done:,}/{self.total:,} {self.unit} ({share:.0f} %), {rate:,.1f} {self.unit}/s, "
                f"{ending}{extra}")

    def _say(self, now: float) -> None:
        print(self.line(now), file=self.stream, flush=True)
        self.said, self.last = self.done, now

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        elif not self.quiet and self.said is not None and self.said != self.done:
            self._say(time.monotonic())

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

"""Text for people: durations, sizes and docstrings as the CLI and the reports print them."""

from __future__ import annotations

import io
import math
import re

__all__ = ["format_seconds", "format_bytes", "plain_text", "inert", "InertLines", "csv_text"]


def format_seconds(s: float) -> str:
    """``412 µs``, ``3.2 ms``, ``4.61 s``, ``2.5 min``, ``1.2 h``."""
    if s < 1e-3:
        return f"{s * 1e6:.0f} µs"
    if s < 1:
        return f"{s * 1e3:.1f} ms"
    if s < 120:
        return f"{s:.2f} s"
    if s < 7200:
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.1f} h"


def format_bytes(n: float) -> str:
    """``512.0 B``, ``1.5 KiB``, ``256.0 MiB``, ``2.0 GiB``."""
    power = min(3, int(math.log(max(n, 1), 1024)))
    return f"{n / 1024 ** power:.1f} {('B', 'KiB', 'MiB', 'GiB')[power]}"


def inert(text: str) -> str:
    """``text`` with every character a terminal could act on (control characters, line breaks, and any other
    that is not printable but the space) written as its escape (``\\x1b``): what came from a file or a spec
    is printed as data, on one line."""
    return "".join(c if c.isprintable() or c == " " else c.encode("unicode_escape").decode("ascii") for c in text)


class InertLines(io.TextIOBase):
    """A text stream that passes what is written to ``stream`` line by line through :func:`inert`, the line
    breaks kept: a command's standard output prints names and labels from files and specs (a part's name, a
    setting's label) as data, however they were made."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        self._stream.write("\n".join(inert(line) for line in text.split("\n")))
        return len(text)

    def flush(self) -> None:
        self._stream.flush()

    def writable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._stream.fileno()

    def isatty(self) -> bool:
        return self._stream.isatty()

    @property
    def encoding(self) -> str:
        return getattr(self._stream, "encoding", "utf-8")


#: What a spreadsheet executes at the start of a cell (OWASP, "CSV Injection").
_FORMULA = ("=", "+", "-", "@", "\t", "\r")


def csv_text(frame) -> str:
    """``frame`` (a pandas DataFrame) as CSV text, every text cell and column name that a spreadsheet would run
    as a formula (starting with ``= + - @``, a tab or a carriage return) prefixed with ``'``, as OWASP's
    CSV-injection guidance says: a name from a spec or a file is shown, never run. Numbers are written as
    they are (a negative number is a number, not text)."""
    def safe(value):
        return "'" + value if isinstance(value, str) and value.startswith(_FORMULA) else value

    frame = frame.rename(columns=safe)
    text = frame.select_dtypes(include=["object", "string", "category"]).columns
    return frame.assign(**{c: frame[c].map(safe) for c in text}).to_csv(index=False)


_ROLE = re.compile(r":[a-z]+(?::[a-z]+)?:`(~?)([^`<]*?)(?:\s*<[^>]*>)?`")


def plain_text(text: str) -> str:
    """reST markup of a docstring as plain text, as Sphinx shows it: ``:class:`~a.b.C``` → ``C``,
    ``:func:`a.f``` → ``a.f``, ````x```` → ``x``; whitespace runs (line breaks) → one space."""
    text = _ROLE.sub(lambda m: m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2), text)
    return " ".join(text.replace("``", "").split())

"""Stopping a command: Ctrl-C and SIGTERM become an exception at a safe moment, and one line.

:func:`on_signal` is the handler of SIGINT and SIGTERM while a command runs (and, in the ``jaxapf``
program, from its first line, :mod:`.program`). It raises ``KeyboardInterrupt`` (SIGINT) or
:class:`Terminated` (SIGTERM) in the main thread, except while a module is being imported: an
exception raised inside the initialisation of an extension module (jaxlib's, numpy's) can leave it
half made, and the process then crashed (SIGSEGV, or C++'s ``terminate``) instead of stopping. Such
a signal is held until the import ends, then raised. An interrupt that Python can only report as
"Exception ignored" (raised in a garbage-collection callback such as JAX's, or a ``__del__``) is
raised again a moment later by :func:`unraisable`, so the command stops instead of running on. One
that something swallowed whole (a library's ``except BaseException``) is still on record: :func:`received`
lets the program end such a run with the stop's line and status, never a silent 0.
"""

from __future__ import annotations

import signal
import sys
from typing import Any

__all__ = ["Terminated", "on_signal", "received", "unraisable", "stopped"]

#: How often a held signal looks whether the import it waits for has ended [s].
_POLL_S = 0.005
#: The signals :func:`on_signal` took since :func:`received` last read them.
_RECEIVED: list[int] = []


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler's time limit, ``kill``): handled like Ctrl-C, so the run says what it kept."""


def _importing(frame: Any) -> bool:
    """Whether ``frame`` or a frame it was called from is Python's import machinery."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib._bootstrap"):
            return True
        frame = frame.f_back
    return False


def _raise_later(signum: int) -> None:
    """In a helper thread: once the main thread is out of imports (or at once), deliver ``signum`` to it
    again (:func:`on_signal` then raises)."""
    import _thread
    import threading
    import time

    main = threading.main_thread().ident
    time.sleep(_POLL_S)
    while _importing(sys._current_frames().get(main)):
        time.sleep(_POLL_S)
    _thread.interrupt_main(signum)


def on_signal(signum: int, frame: Any) -> None:
    """The handler of SIGINT and SIGTERM (module docstring)."""
    _RECEIVED.append(signum)
    if _importing(frame):
        import _thread

        _thread.start_new_thread(_raise_later, (signum,))
        return
    raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt


def received() -> int | None:
    """The first signal :func:`on_signal` took since the last call (``None``: none), forgetting them all."""
    first = _RECEIVED[0] if _RECEIVED else None
    _RECEIVED.clear()
    return first


def unraisable(hook: Any) -> Any:
    """A ``sys.unraisablehook`` that raises a swallowed interrupt again a moment later (from another
    thread: raised in the hook itself it would be swallowed again) and passes anything else to ``hook``."""
    def handle(report: Any) -> None:
        if isinstance(report.exc_value, KeyboardInterrupt):
            import _thread

            signum = signal.SIGTERM if isinstance(report.exc_value, Terminated) else signal.SIGINT
            _thread.start_new_thread(_raise_later, (signum,))
            return
        hook(report)
    return handle


def stopped(stop: BaseException, who: str, kept: str) -> int:
    """Print the one line of an interrupted (status 130) or terminated (SIGTERM, status 143) command."""
    how = "terminated (SIGTERM)" if isinstance(stop, Terminated) else "interrupted"
    print(f"{who}: {how}; {kept}", file=sys.stderr)
    return 143 if isinstance(stop, Terminated) else 130

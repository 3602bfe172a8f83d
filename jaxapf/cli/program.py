"""The ``jaxapf`` program: Ctrl-C or SIGTERM at any moment ends the process with one line.

This module's first lines, before the command line is imported, install for the whole process (the
entry point of ``jaxapf`` and ``python -m jaxapf``; importing :mod:`jaxapf.cli` as a library changes
nothing):

- :func:`~jaxapf.cli.stops.on_signal` for SIGINT and SIGTERM: the interrupt is raised in the main
  thread, never inside an import (held until it ends);
- a ``sys.unraisablehook`` that raises again an interrupt Python would swallow (:mod:`.stops`);
- a ``sys.excepthook`` for an interrupt that reaches the top (while the command line is imported, or
  between its lines): one line and status 130 (143 for SIGTERM), never a traceback.

Once the command has returned, the process exits with its status: signals during the last clean-up
are ignored, and a stopped command's process ends without tearing down what the stop left running
(an XLA compilation on its threads, whose teardown crashed the process after its line in 1 of 120
tries). A signal that arrives while the interpreter itself starts (Python's ``site`` and
``.pth`` files, before any line of jaxapf runs) is Python's to handle (docs/sweep.md).
"""

import signal
import sys

from .stops import on_signal, stopped, unraisable

__all__ = ["console"]


def _exit(code: int) -> None:
    """Flush the output and end the process with ``code`` at once (no interpreter teardown)."""
    import os

    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _last_resort(kind, value, tb) -> None:
    """``sys.excepthook``: a stop that reached the top is one line and its status, at once."""
    if issubclass(kind, KeyboardInterrupt):
        _exit(stopped(value, "jaxapf", "nothing was written"))
    _excepthook(kind, value, tb)


_excepthook = sys.excepthook
sys.excepthook, sys.unraisablehook = _last_resort, unraisable(sys.unraisablehook)
for _signum in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_signum, on_signal)


def console() -> int:
    """Run the command line (:func:`jaxapf.cli.commands.main`) and return its status. Once it has returned,
    SIGINT and SIGTERM are ignored (the result is final), and the exit skips the last garbage collection
    of everything imported (``gc.freeze``), which is work for nothing at exit."""
    import gc

    try:
        from .commands import main

        code = main()
    except KeyboardInterrupt as stop:  # while the command line is imported: nothing was written yet
        code = stopped(stop, "jaxapf", "nothing was written")
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)
    if code in (130, 143):  # stopped: end now, without tearing down what the stop left running (an XLA
        _exit(code)  # compilation or computation on its threads, whose teardown can crash the process)
    gc.freeze()
    return code

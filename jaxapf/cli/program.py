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
are ignored, and a stopped or refused command's process ends without tearing down what was left
running (an XLA compilation on its threads, whose teardown crashed the process after its line in 1 of
120 tries; the runtime's threads after a refused merge's line, in 1 of 24 forged-spec trials); a stop
that something swallowed while the command ran still ends the process with its line and status, never
0. A signal that arrives while the interpreter itself starts (Python's ``site`` and ``.pth`` files,
before any line of jaxapf runs) is Python's to handle (docs/sweep.md).
"""

import sys


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
    """``sys.excepthook``: a stop that reached the top is one line and its status, at once (``Terminated``,
    :class:`jaxapf.cli.stops.Terminated`, is told by name: nothing is imported before this is in place)."""
    if issubclass(kind, KeyboardInterrupt):
        sigterm = kind.__name__ == "Terminated"
        print(f"jaxapf: {'terminated (SIGTERM)' if sigterm else 'interrupted'}; nothing was written", file=sys.stderr)
        _exit(143 if sigterm else 130)
    _excepthook(kind, value, tb)


# a process multiprocessing spawns runs the program's script again, as __mp_main__ beside its own __main__
_spawned = "__mp_main__" in sys.modules and sys.modules["__mp_main__"] is not sys.modules.get("__main__")
_excepthook = sys.excepthook
if not _spawned:
    sys.excepthook = _last_resort

import signal  # noqa: E402  (after the hook: from here on an interrupt is one line)

from .stops import Terminated, on_signal, received, stopped, unraisable  # noqa: E402

__all__ = ["console"]

if not _spawned:
    sys.unraisablehook = unraisable(sys.unraisablehook)
    for _signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(_signum, on_signal)


def _end_children() -> None:
    """Stop the processes this one started (the report's worker; a stop skips the pools' own shutdown)."""
    if "multiprocessing" not in sys.modules:
        return
    import multiprocessing
    import multiprocessing.util

    children = multiprocessing.active_children()
    for child in children:
        child.terminate()
    for child in children:
        child.join(timeout=2.0)
        if child.is_alive():
            child.kill()
    multiprocessing.util._exit_function()  # what its own exit does: release its queues' semaphores


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
    swallowed = received()
    if code == 0 and swallowed is not None:  # a stop some library swallowed whole: the command ran to its end
        stop = Terminated() if swallowed == signal.SIGTERM else KeyboardInterrupt()
        code = stopped(stop, "jaxapf", "the command had finished before it stopped: its output is complete")
    if code in (2, 130, 143):  # refused or stopped: end now, without tearing down what is left running (an
        _end_children()  # XLA compilation or computation on its threads, or the runtime's own threads, whose
        _exit(code)  # teardown can crash the process after its line), and with no process of ours left behind
    gc.freeze()
    return code

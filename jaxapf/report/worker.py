"""The report's second process: it draws the figures that need only the episode rows and the gallery
(:class:`RowWorker`) while the report's process computes its statistics. The command line spawns it
(:func:`spawn`) before the report's own imports, so that its imports run beside them; this module
imports nothing heavy itself."""

from __future__ import annotations

import concurrent.futures
import contextlib
import gc
import multiprocessing
import os
import pathlib
from typing import Any, Mapping, Sequence

__all__ = ["RowWorker", "spawn", "close"]


def _import() -> None:
    """The worker's imports, made while the report's process makes its own."""
    from .. import simulate  # noqa: F401
    from . import figures, gallery  # noqa: F401


#: How often the worker looks whether the report's process is still its parent [s].
_WATCH_S = 0.25


def _watch(parent: int) -> None:
    """The worker's first step: it ends when the report's process ``parent`` ends, however it ends
    (``kill -9``, SIGHUP): at once on Linux (the parent-death signal), and on any system within
    :data:`_WATCH_S` (a thread looks whether its parent is still ``parent``)."""
    import sys
    import threading
    import time

    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before the signal was asked for
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(_WATCH_S)
        os._exit(1)

    threading.Thread(target=watch, name="jaxapf-parent-watch", daemon=True).start()


def spawn() -> concurrent.futures.ProcessPoolExecutor | None:
    """A one-process pool (spawned: JAX is not fork-safe) already importing what the worker needs,
    or None where no process can be started here. The worker ignores Ctrl-C; a stopped report ends it
    (:mod:`jaxapf.cli.program`), and a report's process that dies any other way takes it along
    (:func:`_watch`)."""
    import signal
    import threading

    with contextlib.ExitStack() as stack:
        if threading.current_thread() is threading.main_thread():
            # the worker is started with Ctrl-C ignored (a child keeps an ignored signal across exec): Ctrl-C
            # reaches only the report's process, which ends the worker itself (no second traceback); this
            # process holds a Ctrl-C of that moment (blocked, it stays pending) and takes it once it is back
            held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            stack.callback(signal.pthread_sigmask, signal.SIG_SETMASK, held)
            stack.callback(signal.signal, signal.SIGINT, signal.signal(signal.SIGINT, signal.SIG_IGN))
        try:
            pool = concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                                          initializer=_watch, initargs=(os.getpid(),))
            pool.submit(_import)
        except OSError:
            return None
    return pool


def close(pool: concurrent.futures.ProcessPoolExecutor, wait: bool = True, stop: bool = False) -> None:
    """Shut ``pool`` down, cancelling what has not started; its process exits without a last garbage
    collection of everything it imported (``gc.freeze``), which is work for nothing at exit. ``stop``: end
    the work under way too (a stopped report): its process is terminated and the pool's own threads and
    queues are wound down before this returns, so nothing of it outlives the report."""
    if stop:
        for process in multiprocessing.active_children():  # the pool's process: the report starts no other
            process.terminate()
        pool.shutdown(wait=True, cancel_futures=True)
        return
    try:
        pool.submit(gc.freeze)
    except (RuntimeError, concurrent.futures.process.BrokenProcessPool):
        pass
    pool.shutdown(wait=wait, cancel_futures=True)


#: The JAX settings a worker copies from the report's process (compilation cache, precision).
_JAX_SETTINGS = ("jax_enable_x64", "jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
                 "jax_persistent_cache_min_entry_size_bytes")


def _row_work(sel: Any, meta: Mapping, options: Any, figdir: pathlib.Path,
              jax_settings: Mapping[str, Any] | None = None,
              plugins: Sequence[tuple[str, str | None]] = ()) -> tuple[list, list, list[str]]:
    """:func:`~jaxapf.report.figures.row_figures`, then the gallery: ``(figures, gallery figures, notes)``.
    In a second process: with the report's JAX settings and its plugins (:data:`jaxapf.spec.plugins.LOADED`)."""
    from ..spec.plugins import load_plugin
    from .figures import row_figures
    from .gallery import gallery, resimulate

    if jax_settings:
        import jax

        for key, value in jax_settings.items():
            jax.config.update(key, value)
    for name, path in plugins:
        load_plugin(name, "plugin", path)
    figures, notes = row_figures(sel, options, figdir)
    shown, gallery_notes = gallery(sel, resimulate(sel, meta, options), options, figdir)
    return figures, shown, notes + gallery_notes


class RowWorker:
    """The figures drawn from the rows alone (:func:`~jaxapf.report.figures.row_figures`) and the
    gallery (:mod:`jaxapf.report.gallery`), made in a second (spawned) process while the
    report's process computes its statistics and the figures drawn from them (a thread would not do:
    tracing the re-simulations and drawing are Python work). ``pool``: a process started earlier
    (:func:`spawn`), else one is started on entering. ``result()`` gives
    ``(figures, gallery figures, notes)``. With ``--gallery 0``, or where no process can be started,
    ``result()`` makes them in this process."""

    def __init__(self, sel: Any, meta: Mapping, options: Any, figdir: pathlib.Path,
                 pool: concurrent.futures.ProcessPoolExecutor | None = None):
        self._args = (sel, meta, options, figdir)
        self._pool, self._owned, self._future = pool, pool is None, None

    def __enter__(self) -> RowWorker:
        if self._args[2].gallery == 0:  # no JAX work: not worth a second process
            return self
        import jax

        from ..spec.plugins import LOADED

        if self._pool is None:
            self._pool = spawn()
        settings = {key: getattr(jax.config, key) for key in _JAX_SETTINGS}
        try:
            if self._pool is not None:
                self._future = self._pool.submit(_row_work, *self._args, settings, tuple(LOADED))
        except (OSError, concurrent.futures.process.BrokenProcessPool):  # result() makes them here
            self._future = None
        return self

    def result(self) -> tuple[list, list, list[str]]:
        if self._future is not None:
            try:
                return self._future.result()
            except concurrent.futures.process.BrokenProcessPool:
                pass
        return _row_work(*self._args)

    def __exit__(self, *exc) -> None:
        if self._pool is not None and self._owned:  # on an error or Ctrl-C, the job is cancelled, not awaited
            close(self._pool, wait=exc[0] is None)

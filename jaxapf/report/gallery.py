"""The gallery of a report (the worst failed episodes, re-simulated from their seeds and drawn) and
the second process that makes it, with the other figures drawn from the rows alone."""

from __future__ import annotations

import concurrent.futures
import math
import multiprocessing
import pathlib
from typing import Any, Mapping, Sequence

import pandas as pd

from ..plugins import LOADED, load_plugin
from ..validation import ConfigError, first_line
from .document import FigureFile, save_figure
from .figures import row_figures
from .load import report_metrics
from .select import Selection
from .tables import _num

__all__ = ["worst_episodes", "resimulate", "gallery", "RowWorker"]


def worst_episodes(data: pd.DataFrame, count: int) -> list[tuple[str, pd.Series]]:
    """Up to ``count`` failed episodes: collisions (deepest first), stalls and other failures
    (farthest from the goal first), taken in turn, distinct fields before repeats."""
    fails = data[~data["success"]]
    order = ["setting", "family", "field"]
    cats = [
        ("collision", fails[fails["collision"]].sort_values(["min_clearance"] + order, kind="stable")),
        ("stall", fails[~fails["collision"] & fails["stalled"]].sort_values(
            ["final_distance"] + order, ascending=[False, True, True, True], kind="stable")
         if "final_distance" in fails.columns else fails[~fails["collision"] & fails["stalled"]]),
        ("not reached", fails[~fails["collision"] & ~fails["stalled"]].sort_values(
            ["final_distance"] + order, ascending=[False, True, True, True], kind="stable")
         if "final_distance" in fails.columns else fails[~fails["collision"] & ~fails["stalled"]]),
    ]
    queues = [(name, [r for _, r in frame.iterrows()]) for name, frame in cats]
    picked: list[tuple[str, pd.Series]] = []
    seen_fields: set = set()
    taken: set = set()
    for distinct in (True, False):
        progress = True
        while len(picked) < count and progress:
            progress = False
            for name, rows in queues:
                for r in rows:
                    ident = (int(r["setting"]), str(r["family"]), int(r["field"]))
                    if ident in taken or (distinct and (ident[1], ident[2]) in seen_fields):
                        continue
                    picked.append((name, r))
                    taken.add(ident)
                    seen_fields.add((ident[1], ident[2]))
                    progress = True
                    break
                if len(picked) >= count:
                    break
    return picked


def resimulate(sel: Selection, meta: Mapping, options: Any) -> list[tuple[str, pd.Series, Any]]:
    """The ``options.gallery`` worst episodes (:func:`worst_episodes`), each re-simulated with
    :func:`jaxapf.sweep.row_config` and :func:`jaxapf.simulate.simulate_runs`: ``(kind, row, result)``
    with ``result`` either ``(cfg, field, runs)`` or the :class:`ConfigError` that prevented it. Only
    JAX work: :class:`RowWorker` runs it in a second process while the report is made."""
    if options.gallery == 0:
        return []
    from ..simulate import simulate_runs
    from ..sweep import row_config

    if str(meta.get("dtype", "float32")) == "float64":
        import jax

        jax.config.update("jax_enable_x64", True)
    out = []
    for kind, row in worst_episodes(sel.data, options.gallery):
        try:
            cfg = row_config(meta, row.to_dict())
            field, runs, _ = simulate_runs(cfg.family, cfg.seed, cfg.field, [cfg.sim.planner.method], cfg.gains,
                                           cfg.sim, cfg.mpc, cfg.overrides)
            out.append((kind, row, (cfg, field, runs)))
        except ConfigError as err:  # e.g. a planner of a plugin this process cannot import
            out.append((kind, row, err))
    return out


def gallery(sel: Selection, episodes: list[tuple[str, pd.Series, Any]], options: Any,
            figdir: pathlib.Path) -> tuple[list[FigureFile], list[str]]:
    """The figures of the re-simulated ``episodes`` (:func:`resimulate`) and notes."""
    if options.gallery == 0:
        return [], ["gallery skipped (--gallery 0)"]
    if not episodes:
        return [], ["gallery: no failed episode among the reported settings"]
    from ..simulate import plot_trajectories

    rates = report_metrics(sel.data.columns)[0]
    figures, notes = [], []
    for i, (kind, row, result) in enumerate(episodes, 1):
        what = f"{sel.labels[int(row['setting'])]}, {row['family']} field {int(row['field'])}"
        if isinstance(result, ConfigError):
            notes.append(f"gallery: could not re-simulate {what}: {first_line(result)}")
            continue
        cfg, field, runs = result
        run = runs[0]
        recorded = {m: bool(row[m]) for m in rates}
        resim = {m: bool(run.metrics[m]) for m in rates}
        check = "re-simulation matches the recorded outcome" if recorded == resim else (
            "re-simulation differs from the recorded row: recorded "
            + ", ".join(f"{m}={recorded[m]}" for m in rates) + "; re-simulated "
            + ", ".join(f"{m}={resim[m]}" for m in rates))
        fig = plot_trajectories(runs, field, title=f"Worst episode #{i} ({kind}): {what}")
        caption = (f"{kind}: {what} (seed {cfg.seed}); recorded min clearance "
                   f"{_num(row['min_clearance'])} m, final distance {_num(row.get('final_distance', math.nan))} m; "
                   f"re-simulated min clearance {_num(run.metrics['min_clearance'])} m; {check}")
        figures.append(save_figure(fig, f"gallery_{i}", caption, figdir, options.svg))
    return figures, notes


#: The JAX settings a worker copies from the report's process (compilation cache, precision).
_JAX_SETTINGS = ("jax_enable_x64", "jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
                 "jax_persistent_cache_min_entry_size_bytes")


def _row_work(sel: Selection, meta: Mapping, options: Any, figdir: pathlib.Path,
              jax_settings: Mapping[str, Any] | None = None,
              plugins: Sequence[tuple[str, str | None]] = ()) -> tuple[list[FigureFile], list[FigureFile], list[str]]:
    """:func:`~jaxapf.report.figures.row_figures`, then the gallery: ``(figures, gallery figures, notes)``.
    In a second process: with the report's JAX settings and its plugins (:data:`jaxapf.plugins.LOADED`)."""
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
    gallery (:func:`resimulate`, :func:`gallery`), made in a second (spawned) process started on
    entering, while the report's process computes its statistics and the figures drawn from them
    (a thread would not do: tracing the re-simulations and drawing are Python work). ``result()``
    gives ``(figures, gallery figures, notes)``. With ``--gallery 0``, or where no process can be
    started, ``result()`` makes them in this process."""

    def __init__(self, sel: Selection, meta: Mapping, options: Any, figdir: pathlib.Path):
        self._args = (sel, meta, options, figdir)
        self._pool = self._future = None

    def __enter__(self) -> RowWorker:
        if self._args[2].gallery == 0:  # no JAX work: not worth a second process
            return self
        import jax

        settings = {key: getattr(jax.config, key) for key in _JAX_SETTINGS}
        try:
            self._pool = concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
            self._future = self._pool.submit(_row_work, *self._args, settings, tuple(LOADED))
        except OSError:  # no process can be started here: result() makes them in this process
            self._pool = self._future = None
        return self

    def result(self) -> tuple[list[FigureFile], list[FigureFile], list[str]]:
        if self._future is not None:
            try:
                return self._future.result()
            except concurrent.futures.process.BrokenProcessPool:
                pass
        return _row_work(*self._args)

    def __exit__(self, *exc) -> None:
        if self._pool is not None:  # on an error or Ctrl-C here, the worker's job is cancelled, not awaited
            self._pool.shutdown(wait=exc[0] is None, cancel_futures=True)

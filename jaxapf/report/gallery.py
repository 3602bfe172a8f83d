"""The gallery of a report: the worst failed episodes, re-simulated from their seeds and drawn (in the
report's second process, :mod:`jaxapf.report.worker`)."""

from __future__ import annotations

import math
import pathlib
from typing import Any, Mapping

import pandas as pd

from ..io.names import read_own
from ..simulate.figures import plain_text
from ..validation import ConfigError, first_line
from .document import FigureFile, save_figure
from .load import report_metrics, roles
from .select import Selection
from .tables import _num

__all__ = ["worst_episodes", "resimulate", "gallery"]

#: The most an animated gallery figure (GIF) holds [bytes].
GIF_BYTES = 2**30


def worst_episodes(data: pd.DataFrame, count: int) -> list[tuple[str, pd.Series]]:
    """Up to ``count`` failed episodes: collisions (deepest first), stalls and other failures
    (farthest from the goal first; of a swarm: two UAVs colliding, deadlocks and the rest, fewest UAVs
    at their goals first), taken in turn, distinct fields before repeats."""
    role = roles(data.columns)
    fails = data[~data[role.success].astype(bool)]
    order = ["setting", "family", "field"]
    hit, stuck = fails[role.collision].astype(bool), fails[role.stalled].astype(bool)
    far, ascending = ("at_goal", True) if role.swarm else ("final_distance", False)

    def worst(frame: pd.DataFrame) -> pd.DataFrame:
        return (frame.sort_values([far] + order, ascending=[ascending, True, True, True], kind="stable")
                if far in frame.columns else frame)
    cats = [
        ("collision", fails[hit].sort_values([role.clearance] + order, kind="stable")),
        ("deadlock" if role.swarm else "stall", worst(fails[~hit & stuck])),
        ("not reached", worst(fails[~hit & ~stuck])),
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
    :func:`jaxapf.sweep.row_config` and :func:`jaxapf.simulate.simulate_runs` (a swarm's with
    :func:`jaxapf.simulate.swarm.simulate_swarm`): ``(kind, row, result)``
    with ``result`` either ``(cfg, field, runs)`` or the :class:`ConfigError` that prevented it. Only
    JAX work: :class:`jaxapf.report.worker.RowWorker` runs it in a second process while the report is made."""
    if options.gallery == 0:
        return []
    from ..simulate import simulate_runs
    from ..sweep import row_config

    if str(meta.get("dtype", "float32")) == "float64":
        import jax

        jax.config.update("jax_enable_x64", True)
    from ..simulate.swarm import simulate_swarm

    simulate = simulate_swarm if roles(sel.data.columns).swarm else simulate_runs
    out = []
    for kind, row in worst_episodes(sel.data, options.gallery):
        try:
            cfg = row_config(meta, row.to_dict())
            field, runs, _ = simulate(cfg.family, cfg.seed, cfg.field, [cfg.sim.planner.method], cfg.gains,
                                      cfg.sim, cfg.mpc, cfg.overrides)
            out.append((kind, row, (cfg, field, runs)))
        except ConfigError as err:  # e.g. a planner of a plugin this process cannot import
            out.append((kind, row, err))
    return out


def _animation(runs, field, figdir: pathlib.Path, i: int, title: str) -> FigureFile:
    """Episode ``i`` of the gallery animated (``gallery_i_animated.gif``, and ``.mp4`` beside it)."""
    from ..simulate.animate import animate, tracks_of_runs, tracks_of_swarm
    from ..simulate.swarm import SwarmField

    swarm = isinstance(field, SwarmField)
    tracks = tracks_of_swarm(runs, field) if swarm else tracks_of_runs(runs, field)
    stem = f"gallery_{i}_animated"
    animate(tracks, field.field if swarm else field, figdir, stem=stem, title=f"#{i}")
    gif = read_own(figdir / f"{stem}.gif", GIF_BYTES)  # written just now, in a folder it was handed
    return FigureFile(stem, f"{title}, animated (MP4: figures/{stem}.mp4)", gif, format="gif")


@plain_text
def gallery(sel: Selection, episodes: list[tuple[str, pd.Series, Any]], options: Any,
            figdir: pathlib.Path) -> tuple[list[FigureFile], list[str]]:
    """The figures of the re-simulated ``episodes`` (:func:`resimulate`) and notes."""
    if options.gallery == 0:
        return [], ["gallery skipped (--gallery 0)"]
    if not episodes:
        return [], ["gallery: no failed episode among the reported settings"]
    from ..simulate.figures import failure_cause, plot_failure
    from ..simulate.swarm import plot_swarm_snapshots, plot_swarm_trajectories

    role = roles(sel.data.columns)
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
        near = role.clearance
        if role.swarm:
            caption = (f"{kind}: {what} (seed {cfg.seed}), {run.position.shape[0]} UAVs; recorded closest approach "
                       f"between UAVs {_num(row[near])} m, {_num(100 * row['at_goal'])} % at their goals; "
                       f"re-simulated {_num(run.metrics[near])} m, {_num(100 * run.metrics['at_goal'])} %; {check}")
            fig = plot_swarm_trajectories(runs, field)
            figures.append(save_figure(fig, f"gallery_{i}", f"Worst episode #{i}, every UAV's path: {caption}",
                                       figdir, options.svg))
            figures.append(save_figure(plot_swarm_snapshots(runs, field), f"gallery_{i}_snapshots",
                                       f"Worst episode #{i}, the swarm at fractions of its end", figdir, options.svg))
            if options.animate:
                figures.append(_animation(runs, field, figdir, i, f"Worst episode #{i} ({kind}): {what}"))
            continue
        why = failure_cause(run, field)
        tag = ", a bad start" if "bad start" in why else ""
        fig = plot_failure(run, field, f"Worst episode #{i} ({kind}{tag}): {what}")
        caption = (f"{kind}: {what} (seed {cfg.seed}): {why}. Recorded min clearance {_num(row[near])} m, final "
                   f"distance {_num(row.get('final_distance', math.nan))} m; re-simulated min clearance "
                   f"{_num(run.metrics[near])} m; {check}. Left: the top view at the failure, right: the clearance to "
                   "the nearest obstacles over time (dashed: the failure)")
        figures.append(save_figure(fig, f"gallery_{i}", caption, figdir, options.svg))
        if options.animate:
            figures.append(_animation([run], field, figdir, i, f"Worst episode #{i} ({kind}{tag}): {what}"))
    return figures, notes

"""``jaxapf simulate``: one field, several methods side by side, trajectories + the paper's figures.

Each method is one jit-compiled :func:`~jaxapf.engine.rollout` on the same field (same key), so the
runs differ only by the planner. The output folder receives

- ``trajectories.parquet``: one row per (method, sample) with time, position, velocity, applied
  control (NaN on the last sample), distance to goal and clearance to every valid obstacle;
- ``metrics.csv``: one row per method with every registered metric its components measure;
- ``run.json``: the configuration, the field and the package versions, so the run can be traced;
- the figures of :func:`jaxapf.simulate.figures.plot_all` (PNG).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
from typing import Any, Sequence

import jax
import numpy as np
import pandas as pd

from ..config import MPCConfig, SimConfig
from ..datatypes import Scenario
from ..engine import program, rollout
from ..engine.components import metrics_in_use
from ..gains import Gains
from ..io.lock import write_atomic
from ..io.versions import versions
from ..metrics import METRICS, all_metrics, clearance_history, episode_end, episode_metrics, find_metric
from ..progress import Progress
from ..scenarios import FAMILIES, family_params, make_scenarios
from ..text import csv_text
from .figures import Field, Run, plot_all

__all__ = ["simulate_runs", "write_outputs", "format_metrics_table", "defining_field", "DEFINING_SEARCH"]

#: Fields searched for the first of a family's defining kind (``jaxapf simulate`` without ``--field``).
DEFINING_SEARCH = 256


def defining_field(family: str, seed: int, params: Any = None) -> int:
    """The first field (of the first :data:`DEFINING_SEARCH`) of ``family`` at ``seed`` whose kind is the family's
    defining one (:attr:`~jaxapf.scenarios.Family.defining`: ``trap``'s concave cup); 0 for a family of one kind
    or where none of them is."""
    entry = FAMILIES.get(family, "--family")
    if len(entry.kinds) == 1:
        return 0
    kinds = np.asarray(make_scenarios(seed, params or family_params(family), DEFINING_SEARCH).kind)
    hits = np.flatnonzero(kinds == entry.kinds.index(entry.defining))
    return int(hits[0]) if hits.size else 0

_PYTHON = {"bool": bool, "int32": int, "float": float}


@program(static_argnames=("sim", "mpc", "metrics"))
def _episode(scenario: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, metrics: tuple[str, ...]):
    traj = rollout(scenario, gains, sim, mpc)
    return (traj, episode_metrics(traj, scenario, sim, metrics), clearance_history(traj, scenario, sim),
            episode_end(traj, scenario, sim)["end_index"])


def _field(scenario: Scenario, sim: SimConfig, title: str) -> Field:
    obs = jax.tree_util.tree_map(np.asarray, scenario.obstacles)
    keep = obs.valid
    return Field(
        start=np.asarray(scenario.start), goal=np.asarray(scenario.goal),
        obstacle_position=obs.position[keep], obstacle_velocity=obs.velocity[keep],
        obstacle_radius=obs.radius[keep], obstacle_cylinder=obs.cylinder[keep],
        r_uav=sim.vehicle.r_uav, r_goal=sim.episode.r_goal, d_safe=sim.metrics.d_safe, title=title,
    )


def simulate_runs(
    family: str,
    seed: int,
    field_index: int,
    methods: Sequence[str],
    gains: Gains,
    sim: SimConfig,
    mpc: MPCConfig,
    scenario_overrides: dict | None = None,
) -> tuple[Field, list[Run], pd.DataFrame]:
    """Run ``methods`` on field ``field_index`` of ``family`` (seed ``seed``).

    Returns the field, one :class:`~jaxapf.simulate.figures.Run` per method (cut at the episode
    end; its metrics as Python values of their registered type) and the long trajectory table.
    """
    params = family_params(family, **(scenario_overrides or {}))
    batch = make_scenarios(seed, params, np.array([field_index]))
    scenario = jax.tree_util.tree_map(lambda x: x[0], batch)
    valid = np.asarray(scenario.obstacles.valid)
    runs, tables = [], []
    bar = Progress(len(methods), f"simulate {family}", "method", every=2.0)
    bar.update(0)  # a line at once: the first method compiles before it flies
    for method in methods:
        msim = sim.replace(method=method)
        traj, metrics, clear, end = jax.device_get(_episode(scenario, gains, msim, mpc,
                                                            metrics_in_use(msim, METRICS.names())))
        n = int(end) + 1
        goal_distance = np.linalg.norm(traj.position - np.asarray(scenario.goal), axis=1)
        metrics = {k: _PYTHON[METRICS.get(k).dtype](v) for k, v in metrics.items()}
        run = Run(label=method, time=traj.time[:n], position=traj.position[:n], velocity=traj.velocity[:n],
                  clearance=clear[:n][:, valid], goal_distance=goal_distance[:n], metrics=metrics)
        runs.append(run)
        control = np.concatenate([traj.control, np.full((1, 3), np.nan, traj.control.dtype)])[:n]
        table = {"method": method, "step": np.arange(n), "time": run.time}
        for i, axis in enumerate("xyz"):
            table[f"p{axis}"] = run.position[:, i]
            table[f"v{axis}"] = run.velocity[:, i]
            table[f"a{axis}"] = control[:, i]
        table["goal_distance"] = run.goal_distance
        for j, col in enumerate(run.clearance.T):
            table[f"clearance_{j}"] = col
        tables.append(pd.DataFrame(table))
        bar.update(1)
    bar.close()
    kinds = FAMILIES.get(family, "--family").kinds
    kind = f", {kinds[int(scenario.kind)]}" if len(kinds) > 1 and scenario.kind is not None else ""
    title = f"{family} (seed {seed}, field {field_index}{kind})"
    return _field(scenario, sim, title), runs, pd.concat(tables, ignore_index=True)


def format_metrics_table(runs: Sequence[Any]) -> str:
    """A fixed-width table: one row per registered metric some run has (a single UAV's or a swarm's, with
    its unit; ``-`` where a run's components do not measure it), one column per run (anything with a
    ``label`` and a ``metrics`` dict)."""
    def cell(value) -> str:
        if isinstance(value, bool):
            return str(value).lower()
        return f"{value:.3g}" if isinstance(value, float) else str(value)

    names = [n for n, _ in all_metrics() if any(n in r.metrics for r in runs)]
    rows = {f"{n} [{find_metric(n).unit}]" if find_metric(n).unit else n:
            [cell(r.metrics[n]) if n in r.metrics else "-" for r in runs] for n in names}
    return pd.DataFrame(rows, index=[r.label for r in runs]).T.to_string()


def write_outputs(out: pathlib.Path, field: Field, runs: Sequence[Run], table: pd.DataFrame,
                  config: dict) -> list[pathlib.Path]:
    """Write trajectories, metrics, run record and figures to ``out``; returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "trajectories.parquet", out / "metrics.csv", out / "run.json"]
    write_atomic(paths[0], lambda fh: table.to_parquet(fh, index=False), durable=False)
    rows = [{"method": r.label, **{m: r.metrics[m] for m in METRICS if m in r.metrics}} for r in runs]
    write_atomic(paths[1], csv_text(pd.DataFrame(rows)), durable=False)
    record = {
        **config,
        "field": {k: np.asarray(v).tolist() if isinstance(v, np.ndarray) else v
                  for k, v in dataclasses.asdict(field).items()},
        "versions": versions(),
    }
    write_atomic(paths[2], json.dumps(record, indent=2, default=str), durable=False)
    return paths + plot_all(list(runs), field, out)

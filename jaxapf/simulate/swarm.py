"""``jaxapf simulate --family <swarm family>``: one swarm field, several stacks side by side, every UAV drawn.

Each method flies every UAV of the field (:func:`~jaxapf.engine.swarm.swarm_rollout`, one compiled
program per method) on the same field (same key). The output folder receives

- ``trajectories.parquet``: one row per (method, UAV, sample) up to the swarm's end ``E`` (the last
  UAV's end): time, position, velocity, applied control (NaN on the last sample), distance to goal;
- ``metrics.csv``: one row per method with every swarm metric (:func:`~jaxapf.metrics.swarm.swarm_metric_names`);
- ``run.json``: the configuration, the field and the package versions;
- ``swarm_trajectories.png`` (top view of all UAVs, one panel per method) and
  ``swarm_snapshots.png`` (per method, the swarm at 0.25, 0.5, 0.75 and 1 of ``E``).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
from typing import Sequence

import jax
import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch

from ..config import MPCConfig, SimConfig
from ..datatypes.swarm import Swarm
from ..engine import program
from ..engine.swarm import swarm_rollout
from ..gains import Gains
from ..io.lock import write_atomic
from ..io.versions import versions
from ..metrics import find_metric
from ..metrics.swarm import agent_outcomes, swarm_metrics
from ..scenarios.swarms import make_swarms, swarm_params
from ..text import csv_text
from .figures import (
    DPI,
    Field,
    _aspect,
    _draw_obstacles_xy,
    _legend_below,
    _suptitle,
    _title,
    _xy_bounds,
    panel_grid,
    plain_text,
)

__all__ = ["SwarmRun", "SwarmField", "simulate_swarm", "write_swarm_outputs",
           "plot_swarm_trajectories", "plot_swarm_snapshots", "SWARM_FIGURES"]

_PYTHON = {"bool": bool, "int32": int, "float": float}
_SNAPSHOT_FRACTIONS = (0.25, 0.5, 0.75, 1.0)
#: Seconds of path drawn behind each UAV in a snapshot.
_TRAIL_S = 3.0


@dataclasses.dataclass(frozen=True, eq=False)
class SwarmField:
    """One swarm field as drawn: every UAV's start and goal (A, 3), and ``field``, the obstacles and the
    vehicle's radii (its own start and goal are UAV 0's)."""

    starts: np.ndarray
    goals: np.ndarray
    field: Field

    @property
    def agents(self) -> int:
        return int(self.starts.shape[0])


@dataclasses.dataclass(frozen=True, eq=False)
class SwarmRun:
    """One swarm episode of one method, cut at the swarm's end ``E``.

    Attributes:
      label: the method.
      time: (n,) sample times [s], ``n = E + 1``.
      position, velocity: (A, n, 3).
      end: (A,) each UAV's end sample ``e_a``; success: (A,) whether it reached its goal first;
      hit: (A,) the sample at which it collided (with an obstacle or another UAV), -1 if it did not.
      metrics: the swarm metrics of the episode.
    """

    label: str
    time: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    end: np.ndarray
    success: np.ndarray
    hit: np.ndarray
    metrics: dict

    def summary(self) -> str:
        """``"14/16 at goal, UAVs collide, deadlock"``."""
        words = [f"{int(self.success.sum())}/{len(self.success)} at goal"]
        if self.metrics.get("agent_collision"):
            words.append("UAVs collide")
        if self.metrics.get("obstacle_collision"):
            words.append("obstacle hit")
        if self.metrics.get("deadlock"):
            words.append("deadlock")
        return ", ".join(words)


@program(static_argnames=("sim", "mpc"))
def _episode(swarm: Swarm, gains: Gains, sim: SimConfig, mpc: MPCConfig):
    traj = swarm_rollout(swarm, gains, sim, mpc)
    return traj, swarm_metrics(traj, swarm, sim), agent_outcomes(traj, swarm, sim)


def simulate_swarm(family: str, seed: int, field_index: int, methods: Sequence[str], gains: Gains, sim: SimConfig,
                   mpc: MPCConfig, scenario_overrides: dict | None = None
                   ) -> tuple[SwarmField, list[SwarmRun], pd.DataFrame]:
    """Fly ``methods`` on field ``field_index`` of swarm ``family`` (seed ``seed``; ``scenario_overrides``:
    the family's parameters, e.g. ``agents``). Returns the field, one :class:`SwarmRun` per method and
    the long trajectory table (module docstring)."""
    params = swarm_params(family, **(scenario_overrides or {}))
    swarm = jax.tree_util.tree_map(lambda x: x[0], make_swarms(seed, params, np.array([field_index])))
    runs, tables = [], []
    for method in methods:
        traj, metrics, agents = jax.device_get(_episode(swarm, gains, sim.replace(method=method), mpc))
        last = int(np.max(agents["end"]))
        n = last + 1
        hit = np.minimum(agents["obstacle_index"], agents["agent_index"])
        hit = np.where((hit <= agents["end"]) & ~agents["success"], hit, -1)
        metrics = {k: _PYTHON[find_metric(k).dtype](v) for k, v in metrics.items()}
        run = SwarmRun(method, np.asarray(traj.time[0, :n], np.float64), np.asarray(traj.position[:, :n], np.float64),
                       np.asarray(traj.velocity[:, :n], np.float64), np.asarray(agents["end"]),
                       np.asarray(agents["success"], bool), hit, metrics)
        runs.append(run)
        control = np.concatenate([traj.control, np.full(traj.control.shape[:1] + (1, 3), np.nan)], axis=1)[:, :n]
        a_count = run.position.shape[0]
        table = {"method": method, "agent": np.repeat(np.arange(a_count), n), "step": np.tile(np.arange(n), a_count),
                 "time": np.tile(run.time, a_count)}
        for i, axis in enumerate("xyz"):
            table[f"p{axis}"] = run.position[:, :, i].reshape(-1)
            table[f"v{axis}"] = run.velocity[:, :, i].reshape(-1)
            table[f"a{axis}"] = control[:, :, i].reshape(-1)
        table["goal_distance"] = np.linalg.norm(run.position - np.asarray(swarm.goal)[:, None], axis=-1).reshape(-1)
        tables.append(pd.DataFrame(table))
    obs = jax.tree_util.tree_map(np.asarray, swarm.obstacles)
    keep = obs.valid
    starts, goals = np.asarray(swarm.start, np.float64), np.asarray(swarm.goal, np.float64)
    title = f"{family}, {params.agents} UAVs (seed {seed}, field {field_index})"
    field = Field(start=starts[0], goal=goals[0], obstacle_position=obs.position[keep],
                  obstacle_velocity=obs.velocity[keep], obstacle_radius=obs.radius[keep],
                  obstacle_cylinder=obs.cylinder[keep], r_uav=sim.vehicle.r_uav, r_goal=sim.episode.r_goal,
                  d_safe=sim.metrics.d_safe, title=title)
    return SwarmField(starts, goals, field), runs, pd.concat(tables, ignore_index=True)


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------


def agent_colors(agents: int) -> np.ndarray:
    """One colour per UAV (RGBA rows): ``tab10``/``tab20`` up to 20 UAVs, ``turbo`` beyond."""
    if agents <= 10:
        return colormaps["tab10"](np.arange(agents))
    if agents <= 20:
        return colormaps["tab20"](np.arange(agents))
    return colormaps["turbo"](np.linspace(0.05, 0.95, agents))


def _bounds(runs: Sequence[SwarmRun], swarm: SwarmField, times: Sequence[float]):
    """x–y limits holding every UAV's start, goal and path and the obstacles at ``times``."""
    lo = np.minimum(swarm.starts.min(axis=0), swarm.goals.min(axis=0))
    hi = np.maximum(swarm.starts.max(axis=0), swarm.goals.max(axis=0))
    field = dataclasses.replace(swarm.field, start=lo, goal=hi)
    flat = [dataclasses.replace(r, position=r.position.reshape(-1, 3)) for r in runs]
    return _xy_bounds(flat, field, times)


def _draw_ends(ax, swarm: SwarmField, colors: np.ndarray) -> None:
    """Each UAV's start (square) and goal (circle of radius ``r_goal``) in its colour."""
    for a in range(swarm.agents):
        ax.plot(*swarm.starts[a, :2], "s", color=colors[a], markeredgecolor="black", markersize=4, zorder=5)
        ax.add_patch(Circle(tuple(swarm.goals[a, :2]), swarm.field.r_goal, fill=False, edgecolor=colors[a],
                            linewidth=1.0, zorder=4))


def _handles(swarm: SwarmField, runs: Sequence[SwarmRun]) -> list:
    handles = [Line2D([], [], color="gray", linewidth=1.6, label="a UAV's path (one colour per UAV; dot: end)"),
               Line2D([], [], marker="s", linestyle="", color="gray", markeredgecolor="black", label="start"),
               Line2D([], [], marker="o", linestyle="", markerfacecolor="none", color="gray",
                      label="goal (r_goal circle)")]
    if swarm.field.n_obstacles:
        handles.append(Patch(facecolor="tab:red", alpha=0.35, label="obstacle (at t = 0)"))
    if any(np.any(r.hit >= 0) for r in runs):
        handles.append(Line2D([], [], marker="X", linestyle="", color="red", markeredgecolor="black", markersize=9,
                              label="collision"))
    return handles


def plot_swarm_trajectories(runs: Sequence[SwarmRun], swarm: SwarmField) -> Figure:
    """Top view (x–y) of every UAV's path, one panel per method; obstacles at t = 0."""
    colors = agent_colors(swarm.agents)
    xlim, ylim = _bounds(runs, swarm, [r.time[-1] for r in runs])
    fig, axes = panel_grid(len(runs), (4.6, 4.3 * _aspect(xlim, ylim) + 0.5), (0.4, 1.4), sharex=True, sharey=True)
    for ax, run in zip(axes, runs):
        _draw_obstacles_xy(ax, swarm.field, 0.0)
        _draw_ends(ax, swarm, colors)
        for a in range(swarm.agents):
            p = run.position[a, : run.end[a] + 1]
            ax.plot(p[:, 0], p[:, 1], "-", color=colors[a], linewidth=1.4, zorder=4)
            ax.plot(*p[-1, :2], "o", color=colors[a], markeredgecolor="black", markersize=4, zorder=5.5)
            if run.hit[a] >= 0:
                ax.plot(*run.position[a, run.hit[a], :2], "X", color="red", markeredgecolor="black", markersize=9,
                        zorder=6)
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_title(f"{run.label}: {run.summary()}", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="box")
        ax.grid(True, linewidth=0.4, alpha=0.5)
    _legend_below(fig, _handles(swarm, runs))
    _suptitle(fig, _title("Every UAV's path (top view)", swarm.field))
    return fig


def plot_swarm_snapshots(runs: Sequence[SwarmRun], swarm: SwarmField,
                         fractions: Sequence[float] = _SNAPSHOT_FRACTIONS) -> Figure:
    """Per method, a row of panels at ``fractions`` of the swarm's end ``E``: every UAV as a disc of its
    radius (to scale) with the last :data:`_TRAIL_S` seconds of its path, the obstacles where they are."""
    colors = agent_colors(swarm.agents)
    n, k = len(runs), len(fractions)
    xlim, ylim = _bounds(runs, swarm, [f * r.time[-1] for r in runs for f in fractions])
    fig = Figure(figsize=(3.3 * k + 0.6, (3.0 * _aspect(xlim, ylim) + 0.8) * n + 1.0), layout="constrained")
    grid = fig.subplots(n, k, squeeze=False, sharex=True, sharey=True)
    step = float(runs[0].time[1] - runs[0].time[0]) if len(runs[0].time) > 1 else 1.0
    trail = max(int(round(_TRAIL_S / step)), 1)
    for axes, run in zip(grid, runs):
        for ax, frac in zip(axes, fractions):
            i = int(round(frac * (len(run.time) - 1)))
            t = float(run.time[i])
            _draw_obstacles_xy(ax, swarm.field, t)
            _draw_ends(ax, swarm, colors)
            for a in range(swarm.agents):
                j = min(i, run.end[a])  # an ended UAV stays where it ended
                p = run.position[a, max(j - trail, 0): j + 1]
                ax.plot(p[:, 0], p[:, 1], "-", color=colors[a], linewidth=1.0, alpha=0.8, zorder=4)
                ax.add_patch(Circle(tuple(run.position[a, j, :2]), swarm.field.r_uav, facecolor=colors[a],
                                    edgecolor="black", linewidth=0.6, zorder=6))
                if 0 <= run.hit[a] <= i:
                    ax.plot(*run.position[a, run.hit[a], :2], "X", color="red", markeredgecolor="black",
                            markersize=8, zorder=7)
            ax.set_xlim(*xlim)
            ax.set_ylim(*ylim)
            ax.set_aspect("equal", adjustable="box")
            ax.grid(True, linewidth=0.4, alpha=0.5)
            head = f"{run.label}: {run.summary()}" if ax is axes[0] else run.label
            ax.set_title(f"{head}\nt = {t:.1f} s ({frac:g} E, E = {run.time[-1]:.1f} s)" if ax is axes[0]
                         else f"{head}\nt = {t:.1f} s ({frac:g} E)", fontsize=9)
            if ax is grid[-1][0] or ax in grid[-1]:
                ax.set_xlabel("x [m]")
            if ax is axes[0]:
                ax.set_ylabel("y [m]")
    _legend_below(fig, _handles(swarm, runs))
    _suptitle(fig, _title(f"The swarm at fractions of its end E (trails: last {_TRAIL_S:g} s)", swarm.field))
    return fig


#: File name -> figure function, in the order :func:`write_swarm_outputs` writes them.
SWARM_FIGURES = {"swarm_trajectories.png": plot_swarm_trajectories, "swarm_snapshots.png": plot_swarm_snapshots}


@plain_text
def write_swarm_outputs(out: pathlib.Path, swarm: SwarmField, runs: Sequence[SwarmRun], table: pd.DataFrame,
                        config: dict) -> list[pathlib.Path]:
    """Write trajectories, metrics, run record and figures to ``out``; returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "trajectories.parquet", out / "metrics.csv", out / "run.json"]
    write_atomic(paths[0], lambda fh: table.to_parquet(fh, index=False), durable=False)
    write_atomic(paths[1], csv_text(pd.DataFrame([{"method": r.label, **r.metrics} for r in runs])),
                 durable=False)
    record = {**config, "starts": swarm.starts.tolist(), "goals": swarm.goals.tolist(),
              "field": {k: np.asarray(v).tolist() if isinstance(v, np.ndarray) else v
                        for k, v in dataclasses.asdict(swarm.field).items() if k not in ("start", "goal")},
              "versions": versions()}
    write_atomic(paths[2], json.dumps(record, indent=2, default=str), durable=False)
    for name, make in SWARM_FIGURES.items():
        fig = make(runs, swarm)
        write_atomic(out / name, lambda fh, fig=fig: fig.savefig(fh, dpi=DPI, format="png"), durable=False)
        fig.clear()
        paths.append(out / name)
    return paths

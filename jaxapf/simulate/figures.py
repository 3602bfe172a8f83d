"""The paper's figures (section 4) for ``jaxapf simulate``, drawn from plain numpy arrays.

Every figure is a :class:`matplotlib.figure.Figure` built without ``pyplot``: nothing here selects,
switches or depends on a GUI backend, so the module is safe to import next to an interactive
session, and :func:`plot_all` renders through the Agg canvas that ``Figure.savefig`` attaches.

=========================  ==========================================================  =========
file                       content                                                     paper
=========================  ==========================================================  =========
``trajectories.png``       top view (x–y), one panel per run                           Fig. 1
``snapshots.png``          per run, the path at 0.25, 0.5, 0.75, 1 of the time to goal Fig. 2
``obstacle_distance.png``  clearance to the nearby obstacles over time, per run        Fig. 3
``goal_distance.png``      distance to goal over time, all runs on one axes            Fig. 4
``trajectory_3d.png``      3-D view of each run from two angles                        Fig. 5
=========================  ==========================================================  =========

Colours are fixed per run label (:func:`run_colors`): a registered planner's own colour (the
paper's method ``direction_velocity`` blue, ``basic`` orange, ``direction`` purple), a spare
colour otherwise; obstacles are red and the goal green in every figure.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import pathlib
import textwrap
from typing import Callable, Mapping, Sequence

import matplotlib
import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, FancyArrowPatch, Patch
from matplotlib.ticker import MaxNLocator

from ..io.lock import write_atomic

__all__ = [
    "Run",
    "Field",
    "FIGURES",
    "run_colors",
    "outcome",
    "failure_cause",
    "plot_failure",
    "plot_trajectories",
    "plot_snapshots",
    "plot_obstacle_distance",
    "plot_goal_distance",
    "plot_trajectory_3d",
    "plot_all",
]

#: Colours of labels that are not registered planners with a colour, in the order the runs come.
_SPARE_COLORS = ("tab:cyan", "tab:brown", "tab:pink", "tab:olive", "tab:gray", "black")
_OBSTACLE_COLOR = "tab:red"
_GOAL_COLOR = "tab:green"
_SNAPSHOT_FRACTIONS = (0.25, 0.5, 0.75, 1.0)


# --------------------------------------------------------------------------------------------
# input contract
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class Run:
    """One episode of one method, cut at its end (goal reached, collision or ``t_max``).

    Attributes:
      label: method name, e.g. ``"basic"``; picks the colour (:func:`run_colors`).
      time: (n,) sample times [s].
      position: (n, 3) UAV position [m].
      velocity: (n, 3) UAV velocity [m/s].
      clearance: (n, M) surface clearance to each valid obstacle [m] (``M`` may be 0).
      goal_distance: (n,) distance to the goal [m].
      metrics: the episode's metrics (SPEC 6); read here: ``success``, ``collision``, ``stalled``,
        ``time_to_goal`` (NaN if not reached), ``final_distance``. Missing keys are derived from
        the arrays where possible.
    """

    label: str
    time: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    clearance: np.ndarray
    goal_distance: np.ndarray
    metrics: Mapping[str, float] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        time = np.asarray(self.time, dtype=np.float64).reshape(-1)
        n = time.shape[0]
        if n == 0:
            raise ValueError(f"run {self.label!r} has no samples")
        position = np.asarray(self.position, dtype=np.float64)
        velocity = np.asarray(self.velocity, dtype=np.float64)
        for name, arr in (("position", position), ("velocity", velocity)):
            if arr.shape != (n, 3):
                raise ValueError(f"run {self.label!r}: {name} has shape {arr.shape}; expected ({n}, 3)")
        clearance = np.asarray(self.clearance, dtype=np.float64)
        if clearance.size == 0:
            clearance = clearance.reshape(n, 0)
        if clearance.ndim != 2 or clearance.shape[0] != n:
            raise ValueError(f"run {self.label!r}: clearance has shape {clearance.shape}; expected ({n}, M)")
        goal_distance = np.asarray(self.goal_distance, dtype=np.float64).reshape(-1)
        if goal_distance.shape != (n,):
            raise ValueError(f"run {self.label!r}: goal_distance has shape {goal_distance.shape}; expected ({n},)")
        for name, arr in (("time", time), ("position", position), ("velocity", velocity),
                          ("clearance", clearance), ("goal_distance", goal_distance)):
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "metrics", dict(self.metrics))

    @property
    def t_end(self) -> float:
        return float(self.time[-1])


@dataclasses.dataclass(frozen=True, eq=False)
class Field:
    """The static description of one obstacle field (valid obstacles only).

    Attributes:
      start, goal: (3,) [m].
      obstacle_position: (M, 3) centres at t = 0 [m]; obstacle_velocity: (M, 3) [m/s];
      obstacle_radius: (M,) [m]; obstacle_cylinder: (M,) True for a vertical cylinder.
      r_uav, r_goal, d_safe: UAV radius, goal tolerance, safety clearance [m].
      title: shown as the figures' super-title, e.g. ``"paper_static (seed 0)"``.
    """

    start: np.ndarray
    goal: np.ndarray
    obstacle_position: np.ndarray
    obstacle_velocity: np.ndarray
    obstacle_radius: np.ndarray
    obstacle_cylinder: np.ndarray
    r_uav: float
    r_goal: float
    d_safe: float
    title: str = ""

    def __post_init__(self) -> None:
        radius = np.asarray(self.obstacle_radius, dtype=np.float64).reshape(-1)
        m = radius.shape[0]
        position = np.asarray(self.obstacle_position, dtype=np.float64).reshape(m, 3)
        velocity = np.asarray(self.obstacle_velocity, dtype=np.float64).reshape(m, 3)
        cylinder = np.asarray(self.obstacle_cylinder, dtype=bool).reshape(-1)
        if cylinder.shape != (m,):
            raise ValueError(f"obstacle_cylinder has shape {cylinder.shape}; expected ({m},)")
        for name, value in (("start", self.start), ("goal", self.goal)):
            arr = np.asarray(value, dtype=np.float64)
            if arr.shape != (3,):
                raise ValueError(f"{name} has shape {arr.shape}; expected (3,)")
            object.__setattr__(self, name, arr)
        for name, arr in (("obstacle_position", position), ("obstacle_velocity", velocity),
                          ("obstacle_radius", radius), ("obstacle_cylinder", cylinder)):
            object.__setattr__(self, name, arr)
        for name in ("r_uav", "r_goal", "d_safe"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def n_obstacles(self) -> int:
        return int(self.obstacle_radius.shape[0])

    def obstacles_at(self, t: float) -> np.ndarray:
        """Obstacle centres (M, 3) at time ``t`` (constant velocity)."""
        return self.obstacle_position + self.obstacle_velocity * float(t)

    @property
    def moving(self) -> np.ndarray:
        """(M,) True where an obstacle has a non-zero velocity."""
        return np.linalg.norm(self.obstacle_velocity, axis=1) > 1e-9


# --------------------------------------------------------------------------------------------
# run summaries
# --------------------------------------------------------------------------------------------


def run_colors(runs: Sequence[Run]) -> dict[str, str]:
    """Colour per run label: a registered planner's colour unless an earlier run has it, the next
    unused spare colour otherwise (nine planners side by side shared one brown)."""
    from ..planners import PLANNERS

    colors: dict[str, str] = {}
    for run in runs:
        if run.label in colors:
            continue
        own = PLANNERS.get(run.label).color if run.label in PLANNERS else None
        used = set(colors.values())
        if own is None or own in used:
            own = next((c for c in _SPARE_COLORS if c not in used), "black")
        colors[run.label] = own
    return colors


def _flag(metrics: Mapping[str, float], key: str) -> bool | None:
    value = metrics.get(key)
    if value is None:
        return None
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return bool(value) if math.isfinite(value) else None


def _time_to_goal(run: Run, field: Field) -> float:
    """Time the goal was reached [s], NaN if it was not (metrics first, the arrays otherwise)."""
    value = run.metrics.get("time_to_goal")
    if value is not None:
        value = float(value)
        return value if math.isfinite(value) else math.nan
    if _collision_index(run) is not None:
        return math.nan
    inside = np.flatnonzero(run.goal_distance <= field.r_goal)
    return float(run.time[inside[0]]) if inside.size else math.nan


def _collision_index(run: Run) -> int | None:
    """First sample with negative clearance; the last sample when only the metrics say collision."""
    if run.clearance.shape[1]:
        hit = np.flatnonzero(np.any(run.clearance < 0.0, axis=1))
        if hit.size:
            return int(hit[0])
    if _flag(run.metrics, "collision"):
        return len(run.time) - 1
    return None


def _nonfinite_index(run: Run) -> int | None:
    """The first sample whose position is not finite (the ``invalid`` outcome), or None."""
    bad = np.flatnonzero(~np.all(np.isfinite(run.position), axis=1))
    return int(bad[0]) if bad.size else None


def outcome(run: Run, field: Field) -> str:
    """A short outcome text: ``"reached in 42.1 s"``, ``"collision at 12.3 s"``, ``"stalled, 3.2 m from goal"``,
    ``"non-finite (invalid) at 13.3 s"``."""
    bad = _nonfinite_index(run)
    if bad is not None and (_flag(run.metrics, "invalid") or _collision_index(run) is None):
        return f"non-finite (invalid) at {run.time[bad]:.1f} s"
    t_goal = _time_to_goal(run, field)
    final = run.metrics.get("final_distance")
    final = float(final) if final is not None and math.isfinite(float(final)) else float(run.goal_distance[-1])
    hit = _collision_index(run)
    if hit is not None:
        return f"collision at {run.time[hit]:.1f} s"
    if math.isfinite(t_goal):
        return f"reached in {t_goal:.1f} s"
    if _flag(run.metrics, "stalled"):
        return f"stalled, {final:.1f} m from goal"
    return f"not reached, {final:.1f} m from goal at {run.t_end:.1f} s"


# --------------------------------------------------------------------------------------------
# drawing helpers
# --------------------------------------------------------------------------------------------


def _xy_bounds(runs: Sequence[Run], field: Field,
               times: Sequence[float]) -> tuple[tuple[float, float], tuple[float, float]]:
    """Square-ish x–y limits holding start, goal, every path and the obstacles at ``times``."""
    lo = np.minimum(field.start[:2], field.goal[:2]) - field.r_goal
    hi = np.maximum(field.start[:2], field.goal[:2]) + field.r_goal
    for run in runs:
        lo = np.minimum(lo, run.position[:, :2].min(axis=0))
        hi = np.maximum(hi, run.position[:, :2].max(axis=0))
    if field.n_obstacles:
        r = field.obstacle_radius[:, None]
        for t in (0.0, *times):
            c = field.obstacles_at(t)[:, :2]
            lo = np.minimum(lo, (c - r).min(axis=0))
            hi = np.maximum(hi, (c + r).max(axis=0))
    span = max(float(np.max(hi - lo)), 1.0)
    # widen the narrower side to at least 60 % of the wider one: equal-aspect panels stay legible
    short = np.maximum(0.6 * span - (hi - lo), 0.0)
    lo, hi = lo - 0.5 * short, hi + 0.5 * short
    pad = 0.05 * span + 0.5
    return (lo[0] - pad, hi[0] + pad), (lo[1] - pad, hi[1] + pad)


def _aspect(xlim: tuple[float, float], ylim: tuple[float, float]) -> float:
    """Height / width of an equal-aspect x–y panel, kept within [0.6, 1.6] for the figure size."""
    return float(np.clip((ylim[1] - ylim[0]) / (xlim[1] - xlim[0]), 0.6, 1.6))


#: Panels per row of a figure with one panel per run (rows of three stay readable at page width).
PANELS_PER_ROW = 3
#: The figures' resolution (``simulate`` and ``report``), and the widest figure in pixels at it
#: (readable at a page's width).
DPI = 110
MAX_WIDTH = 2400


def plain_text(draw: Callable) -> Callable:
    """``draw`` with matplotlib's mathtext off: a user's label or tag holding ``$`` is drawn as written,
    never parsed (an unbalanced ``$x^{2`` would stop the drawing)."""
    @functools.wraps(draw)
    def drawn(*args, **kwargs):
        with matplotlib.rc_context({"text.parse_math": False}):
            return draw(*args, **kwargs)
    return drawn


def panel_grid(n: int, panel: tuple[float, float], margin: tuple[float, float],
               max_height: float | None = None, **subplot_kw) -> tuple[Figure, np.ndarray]:
    """A constrained-layout figure of ``n`` panels of ``panel`` inches (plus ``margin`` inches for
    titles, labels and legend) in rows of at most :data:`PANELS_PER_ROW`, unused cells removed; at
    most :data:`MAX_WIDTH` px wide at :data:`DPI` and at most 3:1 (a wide figure is given height,
    never squeezed). Returns the figure and its ``n`` axes, flat, in reading order."""
    ncols, nrows = min(n, PANELS_PER_ROW), math.ceil(n / PANELS_PER_ROW)
    width = min(panel[0] * ncols + margin[0], MAX_WIDTH / DPI)
    height = panel[1] * nrows + margin[1]
    height = max(min(height, max_height) if max_height else height, width / 2.9)
    fig = Figure(figsize=(width, height), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False, **subplot_kw).reshape(-1)
    for ax in axes[n:]:
        ax.remove()
    return fig, axes[:n]


def _suptitle(fig, text: str, **kwargs) -> None:
    """Figure title, wrapped to the figure's width."""
    inches = fig.figure.get_figwidth() * (fig.bbox.width / fig.figure.bbox.width)
    width = max(int(inches * 10.5 * 12.0 / float(kwargs.get("fontsize", 12.0))), 30)
    fig.suptitle(textwrap.fill(text, width), **kwargs)


def _time_axis(ax, runs: Sequence[Run]) -> None:
    """Time axis in seconds; a sensible window when every run has a single sample."""
    t0 = min(float(r.time[0]) for r in runs)
    t1 = max(r.t_end for r in runs)
    if t1 <= t0:
        ax.set_xlim(t0, t0 + 1.0)
    ax.set_xlabel("time [s]")


def _draw_obstacles_xy(ax, field: Field, t: float, *, dashed: bool = False, numbers: bool = False) -> None:
    """Obstacle cross-sections at time ``t``: cylinders filled, spheres hatched.

    ``dashed``: outlines of the *moving* obstacles only (where they are at ``t``).
    ``numbers``: write the obstacle number (1-based, as "Obs j" of the clearance plot) inside.
    """
    centres = field.obstacles_at(t)
    for j in (np.flatnonzero(field.moving) if dashed else range(field.n_obstacles)):
        cx, cy = centres[j, :2]
        rho = field.obstacle_radius[j]
        if dashed:
            patch = Circle((cx, cy), rho, fill=False, edgecolor=_OBSTACLE_COLOR, linestyle="--",
                           linewidth=1.0, alpha=0.8, zorder=2)
        else:
            patch = Circle((cx, cy), rho, facecolor=_OBSTACLE_COLOR, edgecolor=_OBSTACLE_COLOR,
                           alpha=0.35 if field.obstacle_cylinder[j] else 0.2,
                           hatch=None if field.obstacle_cylinder[j] else "////", linewidth=1.0, zorder=2)
        ax.add_patch(patch)
        if numbers:
            ax.text(cx, cy, str(j + 1), ha="center", va="center", fontsize=7, color="darkred", zorder=3, clip_on=True)


def _draw_velocity_arrows(ax, field: Field, t_end: float) -> None:
    """Arrow from each moving obstacle's t = 0 centre along its velocity (length |v| t_end, at least 1.5 ρ)."""
    for j in np.flatnonzero(field.moving):
        p0 = field.obstacle_position[j, :2]
        v = field.obstacle_velocity[j, :2]
        speed = float(np.linalg.norm(v))
        if speed < 1e-9:  # moves only vertically: nothing to show from above
            continue
        length = max(speed * t_end, 1.5 * float(field.obstacle_radius[j]), 0.5)
        p1 = p0 + v / speed * length
        ax.add_patch(FancyArrowPatch(tuple(p0), tuple(p1), arrowstyle="-|>", mutation_scale=10,
                                     color="darkred", linewidth=1.0, zorder=3))


def _draw_start_goal_xy(ax, field: Field) -> None:
    ax.add_patch(Circle(tuple(field.goal[:2]), field.r_goal, fill=False, edgecolor=_GOAL_COLOR,
                        linewidth=1.2, zorder=4))
    ax.plot(*field.goal[:2], "o", color=_GOAL_COLOR, markersize=7, zorder=5)
    ax.plot(*field.start[:2], "s", color="black", markersize=6, zorder=5)


def _legend_below(fig: Figure, handles: list) -> None:
    """A legend under the axes in as many columns (at most 5) as fit the figure's width."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    for ncol in range(min(len(handles), 5), 0, -1):
        legend = fig.legend(handles=handles, loc="outside lower center", ncol=ncol, fontsize=8)
        if ncol == 1 or legend.get_window_extent(renderer).width <= 0.98 * fig.bbox.width:
            return
        legend.remove()


def _legend_handles(runs: Sequence[Run], field: Field, colors: Mapping[str, str], *, moving_ghost: bool,
                    uav: bool = False, track: bool = False, end: bool = False) -> list:
    """Proxy artists for a legend: one path per run (with ``end``, its final position as a dot), then
    start, goal, obstacle kinds, collision."""
    handles = [Line2D([], [], color=colors[r.label], linewidth=2, marker="o" if end else None,
                      markeredgecolor="black", markersize=6, label=f"{r.label} path" + (" (dot: end)" if end else ""))
               for r in runs]
    if uav:
        handles += [Line2D([], [], marker="o", linestyle="", color=colors[r.label], markeredgecolor="black",
                           label=f"{r.label} UAV") for r in runs]
    handles.append(Line2D([], [], marker="s", linestyle="", color="black", label="start"))
    handles.append(Line2D([], [], marker="o", linestyle="", color=_GOAL_COLOR, label="goal (r_goal circle)"))
    if np.any(field.obstacle_cylinder):
        handles.append(Patch(facecolor=_OBSTACLE_COLOR, alpha=0.35, label="cylinder obstacle"))
    if np.any(~field.obstacle_cylinder):
        handles.append(Patch(facecolor=_OBSTACLE_COLOR, alpha=0.2, hatch="////", label="sphere obstacle"))
    if np.any(field.moving):
        if moving_ghost:
            handles.append(Patch(fill=False, edgecolor=_OBSTACLE_COLOR, linestyle="--",
                                 label="moving obstacle at run end"))
            handles.append(Line2D([], [], color="darkred", marker=">", label="obstacle velocity"))
        if track:
            handles.append(Line2D([], [], color="darkred", linestyle=":", label="moving obstacle track"))
    if any(_collision_index(r) is not None for r in runs):
        handles.append(Line2D([], [], marker="X", linestyle="", color="red", markeredgecolor="black",
                              markersize=9, label="collision"))
    return handles


def _index_at(run: Run, t: float) -> int:
    """Last sample index with ``time <= t`` (0 if none)."""
    return int(np.clip(np.searchsorted(run.time, t + 1e-9, side="right") - 1, 0, len(run.time) - 1))


def _label_xy(ax) -> None:
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, linewidth=0.4, alpha=0.5)


def _no_runs_guard(runs: Sequence[Run]) -> None:
    if not runs:
        raise ValueError("nothing to plot: no runs given")


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------


def plot_trajectories(runs: Sequence[Run], field: Field, title: str | None = None) -> Figure:
    """Top view (x–y), one panel per run (paper Fig. 1: basic APF stalls, weighted APF goes round);
    ``title`` replaces the default figure title (wrapped to the width either way).

    Obstacles are drawn at t = 0 and numbered as in :func:`plot_obstacle_distance`; a moving
    obstacle also gets a dashed outline where it is at the run's final time and a velocity arrow.
    """
    _no_runs_guard(runs)
    colors = run_colors(runs)
    n = len(runs)
    xlim, ylim = _xy_bounds(runs, field, [r.t_end for r in runs])
    fig, axes = panel_grid(n, (4.6, 4.3 * _aspect(xlim, ylim) + 0.5), (0.4, 1.4), sharex=True, sharey=True)
    for ax, run in zip(axes, runs):
        color = colors[run.label]
        _draw_obstacles_xy(ax, field, 0.0, numbers=True)
        if np.any(field.moving):
            _draw_obstacles_xy(ax, field, run.t_end, dashed=True)
            _draw_velocity_arrows(ax, field, run.t_end)
        _draw_start_goal_xy(ax, field)
        ax.plot(run.position[:, 0], run.position[:, 1], "-", color=color, linewidth=2, zorder=4,
                label=f"{run.label} path")
        # the final position, so that a path that hardly left the start is still seen
        ax.plot(*run.position[-1, :2], "o", color=color, markeredgecolor="black", markersize=6, zorder=5.5)
        hit = _collision_index(run)
        if hit is not None:
            ax.plot(*run.position[hit, :2], "X", color="red", markeredgecolor="black", markersize=12, zorder=6)
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_title(f"{run.label} — {outcome(run, field)}")
        _label_xy(ax)
    handles = _legend_handles(runs, field, colors, moving_ghost=True, end=True)
    _legend_below(fig, handles)
    _suptitle(fig, title or _title("Trajectories (top view, obstacles at t = 0)", field))
    return fig


def _failure_index(run: Run) -> int:
    """The sample a failure is seen at: the first collision, else the last finite sample (a stall, a timeout,
    or the last before the state turned non-finite)."""
    hit = _collision_index(run)
    bad = _nonfinite_index(run)
    if hit is not None and (bad is None or hit < bad):
        return hit
    return len(run.time) - 1 if bad is None else max(bad - 1, 0)


def failure_cause(run: Run, field: Field) -> str:
    """Why an episode failed, in one sentence of measured facts: the outcome, the obstacle nearest at the
    failure, how far the UAV flew, and a *bad start* where it began closer than ``d_safe`` to an obstacle."""
    k = _failure_index(run)
    flown = float(np.linalg.norm(np.diff(run.position[: k + 1], axis=0), axis=1).sum())
    parts = [outcome(run, field) + f" after flying {flown:.2f} m"]
    if run.clearance.shape[1]:
        near = int(np.nanargmin(run.clearance[k]))
        parts.append(f"obstacle {near + 1} nearest there ({run.clearance[k, near]:.2f} m from its surface)")
        start = int(np.nanargmin(run.clearance[0]))
        if run.clearance[0, start] < field.d_safe:
            parts.append(f"a bad start: it began {run.clearance[0, start]:.2f} m from obstacle {start + 1}, "
                         f"inside d_safe = {field.d_safe:g} m")
    return "; ".join(parts)


def plot_failure(run: Run, field: Field, title: str, window: float = 3.0) -> Figure:
    """One failed episode in two panels: the top view zoomed on where it failed (at least ``window`` m
    around it, the path's last 10 s and the obstacles there at that time) and the clearance to the
    nearest obstacles over time, the failure marked in both."""
    k = _failure_index(run)
    colors = run_colors([run])
    fig, (top, ax) = panel_grid(2, (4.4, 3.6), (0.4, 1.2))
    at = run.position[k, :2]
    recent = run.position[(run.time >= run.time[k] - 10.0) & (run.time <= run.time[k]), :2]
    half = max(window, float(np.abs(recent - at).max()) + 0.5 if len(recent) else window)
    _draw_obstacles_xy(top, field, float(run.time[k]), numbers=True)
    _draw_start_goal_xy(top, field)
    top.plot(run.position[: k + 1, 0], run.position[: k + 1, 1], "-", color=colors[run.label], linewidth=2,
             zorder=4)
    top.plot(*at, "X" if _collision_index(run) is not None else "o", color="red", markeredgecolor="black",
             markersize=11, zorder=6)
    top.add_patch(Circle(tuple(at), field.r_uav, fill=False, edgecolor="black", linewidth=0.8, zorder=6))
    top.set_xlim(at[0] - half, at[0] + half)
    top.set_ylim(at[1] - half, at[1] + half)
    top.set_aspect("equal")
    top.set_title(f"at t = {run.time[k]:.1f} s (zoomed)", fontsize=10)
    _label_xy(top)
    chosen, phrase = _obstacles_to_show(run, field, 2.0 * field.d_safe + 3.0, 4)
    palette = list(colormaps["Dark2"].colors)
    for j in chosen:
        ax.plot(run.time, run.clearance[:, j], color=palette[j % len(palette)], linewidth=1.4, label=f"Obs {j + 1}")
    ax.axhline(0.0, color="red", linewidth=1.2, label="collision")
    ax.axhline(field.d_safe, color="black", linestyle=":", linewidth=1.2, label=f"d_safe {field.d_safe:g} m")
    ax.axvline(run.time[k], color="red", linestyle="--", linewidth=0.8)
    if chosen.size:
        ax.set_ylim(min(-0.2, float(np.nanmin(run.clearance[:, chosen])) - 0.1),
                    max(2.0 * field.d_safe + 1.0, 0.5))
    ax.set_title(f"clearance ({phrase})", fontsize=10)
    _time_axis(ax, [run])
    ax.set_ylabel("clearance [m]")
    ax.grid(True, linewidth=0.4, alpha=0.5)
    ax.legend(loc="best", fontsize=7, framealpha=0.8)
    _suptitle(fig, title, fontsize=10)
    return fig


def _title(what: str, field: Field) -> str:
    return f"{what} — {field.title}" if field.title else what


def _snapshot_horizon(run: Run, field: Field) -> tuple[float, bool]:
    t_goal = _time_to_goal(run, field)
    return (t_goal, True) if math.isfinite(t_goal) else (run.t_end, False)


def plot_snapshots(runs: Sequence[Run], field: Field, fractions: Sequence[float] = _SNAPSHOT_FRACTIONS) -> Figure:
    """Per run, a row of panels at ``fractions`` of the time to goal T (paper Fig. 2).

    When the goal was not reached T is the run's final time, and the row's title says so.
    Each panel shows the path so far, the UAV and the obstacles where they are at that instant.
    """
    _no_runs_guard(runs)
    colors = run_colors(runs)
    n, k = len(runs), len(fractions)
    xlim, ylim = _xy_bounds(runs, field, [f * _snapshot_horizon(r, field)[0] for r in runs for f in fractions])
    fig = Figure(figsize=(3.3 * k + 2.2, (3.0 * _aspect(xlim, ylim) + 0.9) * n + 0.4), layout="constrained")
    rows = fig.subfigures(n, 1, squeeze=False)[:, 0]
    first = None
    for sub, run in zip(rows, runs):
        color = colors[run.label]
        horizon, reached = _snapshot_horizon(run, field)
        hit = _collision_index(run)
        if reached:
            basis = f"T = time to goal = {horizon:.1f} s"
        else:
            basis = f"goal not reached ({outcome(run, field)}): T = final time = {horizon:.1f} s"
        axes = sub.subplots(1, k, squeeze=False)[0]
        for ax, frac in zip(axes, fractions):
            if first is None:
                first = ax
            else:
                ax.sharex(first)
                ax.sharey(first)
            i = _index_at(run, frac * horizon)
            t = float(run.time[i])
            _draw_obstacles_xy(ax, field, t)
            _draw_start_goal_xy(ax, field)
            ax.plot(run.position[: i + 1, 0], run.position[: i + 1, 1], "-", color=color, linewidth=1.8, zorder=4)
            ax.plot(*run.position[i, :2], "o", color=color, markeredgecolor="black", markersize=7, zorder=6)
            if hit is not None and hit <= i:
                ax.plot(*run.position[hit, :2], "X", color="red", markeredgecolor="black", markersize=11, zorder=7)
            ax.set_xlim(*xlim)
            ax.set_ylim(*ylim)
            ax.set_title(f"t = {t:.1f} s ({frac:g} T)", fontsize=9)
            _label_xy(ax)
            if ax is not axes[0]:
                ax.tick_params(labelleft=False)
        handles = _legend_handles([run], field, colors, moving_ghost=False, uav=True)
        sub.legend(handles=handles, loc="outside right center", fontsize=7)
        _suptitle(sub, f"{run.label}: {basis}", fontsize=10, fontweight="bold")
    _suptitle(fig, _title("Snapshots at fractions of T (obstacles where they are at that time)", field))
    return fig


def _obstacles_to_show(run: Run, field: Field, near: float, max_lines: int) -> tuple[np.ndarray, str]:
    """Indices of the obstacles to draw and a phrase saying which they are."""
    m = run.clearance.shape[1]
    if m == 0:
        return np.zeros(0, int), "no obstacles"
    closest = np.array([np.min(c[np.isfinite(c)]) if np.any(np.isfinite(c)) else np.inf
                        for c in run.clearance.T])
    order = np.argsort(closest, kind="stable")
    within = order[closest[order] <= near]
    if within.size == 0:
        chosen = order[: min(3, m)]
        phrase = f"none within {near:.3g} m; closest {chosen.size} of {m} shown"
    elif within.size > max_lines:
        chosen = within[:max_lines]
        if within.size == m:
            phrase = f"closest {max_lines} of {m} shown"
        else:
            phrase = f"closest {max_lines} of the {within.size} within {near:.3g} m shown, {m} in all"
    elif within.size == m:
        chosen = within
        phrase = f"all {m} shown"
    else:
        chosen = within
        phrase = f"{within.size} of {m} within {near:.3g} m shown"
    return np.sort(chosen), phrase


def plot_obstacle_distance(runs: Sequence[Run], field: Field, near: float | None = None,
                           max_lines: int = 8) -> Figure:
    """Clearance to each nearby obstacle over time, one panel per run (paper Fig. 3).

    Only obstacles whose clearance comes within ``near`` (default ``2 d_safe + 3`` m) are drawn,
    at most ``max_lines`` (the closest); the title says which. The clearance axis stops at
    ``4 near`` so that the close approaches stay readable. "Obs j" numbers the valid obstacles
    from 1, as in the top view; the colour of an obstacle is the same in every panel.
    """
    _no_runs_guard(runs)
    near = 2.0 * field.d_safe + 3.0 if near is None else float(near)
    n = len(runs)
    fig, axes = panel_grid(n, (5.2, 3.6), (0.4, 0.8), sharex=True, sharey=True)
    # obstacle colours: a palette apart from the run colours and the red collision line
    palette = list(colormaps["Dark2"].colors)
    for ax, run in zip(axes, runs):
        chosen, phrase = _obstacles_to_show(run, field, near, max_lines)
        for j in chosen:
            ax.plot(run.time, run.clearance[:, j], marker="." if len(run.time) == 1 else None,
                    color=palette[j % len(palette)], linestyle=("-", "--", "-.")[(j // len(palette)) % 3],
                    linewidth=1.4, label=f"Obs {j + 1}")
        ax.axhline(0.0, color="red", linewidth=1.2, label="collision (0 m)")
        ax.axhline(field.d_safe, color="black", linestyle=":", linewidth=1.2, label=f"d_safe = {field.d_safe:g} m")
        if chosen.size == 0:
            ax.text(0.5, 0.5, "no obstacles", transform=ax.transAxes, ha="center", va="center", color="gray")
        ax.set_title(f"{run.label} — clearance ({phrase})", fontsize=10)
        _time_axis(ax, runs)
        ax.set_ylabel("clearance [m]")
        ax.grid(True, linewidth=0.4, alpha=0.5)
        ax.legend(loc="best", fontsize=7, ncol=2 if chosen.size > 4 else 1, framealpha=0.8)
    # far-away stretches squash the near approaches that matter: clip the axis at 4 x near
    bottom, top = axes[0].get_ylim()
    if top > 4.0 * near:
        axes[0].set_ylim(bottom, 4.0 * near)
    _suptitle(fig, _title("Distance to obstacles over time (surface clearance)", field))
    return fig


def plot_goal_distance(runs: Sequence[Run], field: Field) -> Figure:
    """Distance to the goal over time, all runs on one axes (paper Fig. 4)."""
    _no_runs_guard(runs)
    colors = run_colors(runs)
    fig = Figure(figsize=(7.5, 4.6), layout="constrained")
    ax = fig.add_subplot()
    for run in runs:
        color = colors[run.label]
        ax.plot(run.time, run.goal_distance, "-", color=color, linewidth=1.8,
                marker="." if len(run.time) == 1 else None, label=f"{run.label} ({outcome(run, field)})")
        t_goal = _time_to_goal(run, field)
        if math.isfinite(t_goal):
            ax.plot(t_goal, run.goal_distance[_index_at(run, t_goal)], "o", color=color, markeredgecolor="black",
                    zorder=5)
        hit = _collision_index(run)
        if hit is not None:
            ax.plot(run.time[hit], run.goal_distance[hit], "X", color="red", markeredgecolor="black",
                    markersize=10, zorder=5)
    ax.axhline(field.r_goal, color=_GOAL_COLOR, linestyle="--", linewidth=1.2, label=f"r_goal = {field.r_goal:g} m")
    if any(_collision_index(r) is not None for r in runs):
        ax.plot([], [], "X", color="red", markeredgecolor="black", linestyle="", label="collision")
    ax.set_ylim(bottom=0.0)
    ax.set_title(_title("Distance to goal over time", field))
    _time_axis(ax, runs)
    ax.set_ylabel("distance to goal [m]")
    ax.grid(True, linewidth=0.4, alpha=0.5)
    ax.legend(loc="best", fontsize=8)
    return fig


def _z_span(runs: Sequence[Run], field: Field, margin: float = 3.0) -> tuple[float, float]:
    zs = [field.start[2], field.goal[2]] + [float(z) for r in runs
                                            for z in (r.position[:, 2].min(), r.position[:, 2].max())]
    return min(zs) - margin, max(zs) + margin


def _draw_obstacles_3d(ax, field: Field, t: float, z_lo: float, z_hi: float) -> None:
    centres = field.obstacles_at(t)
    theta = np.linspace(0.0, 2.0 * np.pi, 25)
    for j in range(field.n_obstacles):
        c, rho = centres[j], field.obstacle_radius[j]
        if field.obstacle_cylinder[j]:
            th, z = np.meshgrid(theta, np.array([z_lo, z_hi]))
            ax.plot_surface(c[0] + rho * np.cos(th), c[1] + rho * np.sin(th), z, color=_OBSTACLE_COLOR,
                            alpha=0.35, linewidth=0, shade=True)
            for zz in (z_lo, z_hi):
                ax.plot(c[0] + rho * np.cos(theta), c[1] + rho * np.sin(theta), np.full_like(theta, zz),
                        color="darkred", linewidth=0.6)
        else:
            u, v = np.meshgrid(theta, np.linspace(0.0, np.pi, 13))
            ax.plot_surface(c[0] + rho * np.cos(u) * np.sin(v), c[1] + rho * np.sin(u) * np.sin(v),
                            c[2] + rho * np.cos(v), color=_OBSTACLE_COLOR, alpha=0.35, linewidth=0, shade=True)


def plot_trajectory_3d(runs: Sequence[Run], field: Field,
                       views: Sequence[tuple[float, float]] = ((25.0, -60.0), (60.0, -125.0))) -> Figure:
    """3-D view of each run from two angles (paper Fig. 5, "View 2"/"View 3"); one row per run.

    All axes have the same scale; the z range is the flight altitude ± 3 m, widened to at least
    0.35 of the horizontal extent. Cylinders are vertical surfaces spanning that range, spheres are
    spheres, both where they are at the run's final time; the centre track of a moving obstacle
    is a dotted line (at mid height for a cylinder). The goal is a green ring of radius ``r_goal``.
    """
    _no_runs_guard(runs)
    colors = run_colors(runs)
    n, k = len(runs), len(views)
    fig = Figure(figsize=(5.4 * k + 0.4, 4.3 * n + 1.0), layout="constrained")
    (x0, x1), (y0, y1) = _xy_bounds(runs, field, [r.t_end for r in runs])
    span = max(x1 - x0, y1 - y0)
    z_lo, z_hi = _z_span(runs, field)
    z_mid = 0.5 * (z_lo + z_hi)
    half = 0.5 * max(z_hi - z_lo, 0.35 * span)  # equal scale on all axes: spheres stay round
    z_lo, z_hi = z_mid - half, z_mid + half
    theta = np.linspace(0.0, 2.0 * np.pi, 49)
    for r_i, run in enumerate(runs):
        color = colors[run.label]
        hit = _collision_index(run)
        for v_i, (elev, azim) in enumerate(views):
            ax = fig.add_subplot(n, k, r_i * k + v_i + 1, projection="3d")
            _draw_obstacles_3d(ax, field, run.t_end, z_lo, z_hi)
            for j in np.flatnonzero(field.moving):
                a, b = field.obstacles_at(0.0)[j], field.obstacles_at(run.t_end)[j]
                za, zb = (z_mid, z_mid) if field.obstacle_cylinder[j] else (a[2], b[2])
                ax.plot([a[0], b[0]], [a[1], b[1]], [za, zb], ":", color="darkred", linewidth=1.0)
            g = field.goal
            ax.plot(g[0] + field.r_goal * np.cos(theta), g[1] + field.r_goal * np.sin(theta),
                    np.full_like(theta, g[2]), "-", color=_GOAL_COLOR, linewidth=2.0)
            ax.plot([g[0]], [g[1]], [g[2]], "o", color=_GOAL_COLOR, markersize=5)
            ax.plot([field.start[0]], [field.start[1]], [field.start[2]], "s", color="black", markersize=5)
            p = run.position
            ax.plot(p[:, 0], p[:, 1], p[:, 2], "-", color=color, linewidth=2.2,
                    marker="o" if len(p) == 1 else None, zorder=10)
            if hit is not None:
                ax.plot([p[hit, 0]], [p[hit, 1]], [p[hit, 2]], "X", color="red", markeredgecolor="black",
                        markersize=10, zorder=11)
            ax.set_xlim(x0, x1)
            ax.set_ylim(y0, y1)
            ax.set_zlim(z_lo, z_hi)
            ax.set_box_aspect((x1 - x0, y1 - y0, z_hi - z_lo), zoom=0.92)
            ax.xaxis.set_major_locator(MaxNLocator(5))
            ax.yaxis.set_major_locator(MaxNLocator(5))
            ax.zaxis.set_major_locator(MaxNLocator(3))
            ax.view_init(elev=elev, azim=azim)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
            ax.set_zlabel("z [m]")
            ax.set_title(f"{run.label} — view {v_i + 1} (elev {elev:g}°, azim {azim:g}°)\n{outcome(run, field)}",
                         fontsize=9)
    handles = _legend_handles(runs, field, colors, moving_ghost=False, track=True)
    _legend_below(fig, handles)
    _suptitle(fig, _title("3-D trajectories (obstacles where they are at the run's final time)", field))
    return fig


#: File name -> figure function, in the order :func:`plot_all` writes them.
FIGURES: dict[str, Callable[[Sequence[Run], Field], Figure]] = {
    "trajectories.png": plot_trajectories,
    "snapshots.png": plot_snapshots,
    "obstacle_distance.png": plot_obstacle_distance,
    "goal_distance.png": plot_goal_distance,
    "trajectory_3d.png": plot_trajectory_3d,
}


@plain_text
def plot_all(runs: Sequence[Run], field: Field, out_dir: pathlib.Path | str, dpi: int = DPI) -> list[pathlib.Path]:
    """Write every figure of :data:`FIGURES` as PNG into ``out_dir`` (created); returns the paths."""
    _no_runs_guard(runs)
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, make in FIGURES.items():
        fig = make(runs, field)
        path = out_dir / name
        write_atomic(path, lambda fh, fig=fig: fig.savefig(fh, dpi=dpi, format="png"), durable=False)
        fig.clear()  # a pyplot-free Figure is freed with its last reference; clear() drops artists now
        paths.append(path)
    return paths

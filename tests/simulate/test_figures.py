"""Figures of ``jaxapf simulate`` on a hand-made field: files written, axes labelled, edge cases."""

from __future__ import annotations

import dataclasses
import io
import math
import re

import numpy as np
import pytest
from matplotlib.figure import Figure

from jaxapf.simulate.figures import (
    FIGURES,
    Field,
    Run,
    outcome,
    plot_all,
    run_colors,
)

UNITS = re.compile(r"\[[^\]]+\]")


def make_field(n_obstacles: int = 4) -> Field:
    pos = np.array([[12.0, 1.5, 5.0], [12.0, -1.5, 5.0], [18.0, 4.0, 5.0], [20.0, -8.0, 5.0]])
    vel = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.8, 0.0]])
    rad = np.array([1.5, 1.5, 1.0, 1.2])
    cyl = np.array([True, True, True, False])
    return Field(start=np.array([0.0, 0.0, 5.0]), goal=np.array([30.0, 0.0, 5.0]),
                 obstacle_position=pos[:n_obstacles], obstacle_velocity=vel[:n_obstacles],
                 obstacle_radius=rad[:n_obstacles], obstacle_cylinder=cyl[:n_obstacles],
                 r_uav=0.3, r_goal=0.5, d_safe=1.0, title="synthetic (seed 0)")


def make_run(label: str, field: Field, path: np.ndarray, dt: float = 0.5, **metrics) -> Run:
    n = len(path)
    time = dt * np.arange(n)
    velocity = np.gradient(path, dt, axis=0) if n > 1 else np.zeros((n, 3))
    centres = field.obstacle_position[None] + field.obstacle_velocity[None] * time[:, None, None]
    rel = path[:, None, :] - centres
    rel = np.where(field.obstacle_cylinder[None, :, None], rel * np.array([1.0, 1.0, 0.0]), rel)
    clearance = np.linalg.norm(rel, axis=-1) - field.obstacle_radius - field.r_uav
    goal_distance = np.linalg.norm(path - field.goal, axis=1)
    return Run(label=label, time=time, position=path, velocity=velocity, clearance=clearance,
               goal_distance=goal_distance, metrics=metrics)


def detour_path(field: Field) -> np.ndarray:
    """Goes round the cluster above it and reaches the goal."""
    s = np.linspace(0.0, 1.0, 70)
    x = 30.0 * s
    y = 6.5 * np.sin(np.pi * s) ** 2
    return np.stack([x, y, np.full_like(s, 5.0)], axis=1)


def stalled_path(field: Field) -> np.ndarray:
    """Approaches the cluster, hovers in front of it, then drifts into obstacle 2."""
    approach = np.stack([np.linspace(0.0, 9.5, 25), np.zeros(25), np.full(25, 5.0)], axis=1)
    hover = np.array([9.5, 0.0, 5.0]) + 0.05 * np.stack([np.sin(np.arange(20)), np.cos(np.arange(20)), np.zeros(20)], 1)
    drift = np.stack([np.linspace(9.5, 10.8, 6), np.linspace(0.0, -1.0, 6), np.full(6, 5.0)], axis=1)
    return np.concatenate([approach, hover, drift])


@pytest.fixture(scope="module")
def example():
    field = make_field()
    good = make_run("direction_velocity", field, detour_path(field), success=1.0, collision=0.0, stalled=0.0,
                    time_to_goal=34.5, final_distance=0.0)
    bad_path = stalled_path(field)
    bad = make_run("basic", field, bad_path, success=0.0, collision=1.0, stalled=1.0, time_to_goal=math.nan,
                   final_distance=float(np.linalg.norm(bad_path[-1] - field.goal)))
    return field, [bad, good]


def figure_legends(fig) -> list:
    """Legends of the figure, of its subfigures (recursively) and of its axes."""
    found = list(fig.legends)
    for sub in getattr(fig, "subfigs", []):
        found += figure_legends(sub)
    return found


def check_figure(fig: Figure) -> None:
    axes = fig.get_axes()
    assert axes
    legends = figure_legends(fig)
    for ax in axes:
        assert ax.get_title(), "every panel has a title"
        assert UNITS.search(ax.get_xlabel()), f"x label without units: {ax.get_xlabel()!r}"
        assert UNITS.search(ax.get_ylabel()), f"y label without units: {ax.get_ylabel()!r}"
        if hasattr(ax, "get_zlabel"):
            assert UNITS.search(ax.get_zlabel())
        if ax.get_legend() is not None:
            legends.append(ax.get_legend())
    assert legends, "every figure has a legend"
    for legend in legends:
        assert legend.get_texts() and all(t.get_text() for t in legend.get_texts())


def test_plot_all_writes_pngs(example, tmp_path):
    field, runs = example
    paths = plot_all(runs, field, tmp_path / "figs")
    assert [p.name for p in paths] == list(FIGURES)
    assert {p.name for p in paths} == {"trajectories.png", "snapshots.png", "obstacle_distance.png",
                                      "goal_distance.png", "trajectory_3d.png"}
    for p in paths:
        data = p.read_bytes()
        assert data.startswith(b"\x89PNG\r\n\x1a\n")
        assert len(data) > 20_000, f"{p.name} is suspiciously small ({len(data)} bytes)"


@pytest.mark.parametrize("name", list(FIGURES))
def test_figure_labels(example, name):
    field, runs = example
    fig = FIGURES[name](runs, field)
    check_figure(fig)
    # one top-level title for the whole figure
    text = fig._suptitle.get_text() if fig._suptitle is not None else fig.get_axes()[0].get_title()
    assert text


def test_panel_contents(example):
    field, runs = example
    fig = FIGURES["trajectories.png"](runs, field)
    titles = [ax.get_title() for ax in fig.get_axes()]
    assert titles[0].startswith("basic") and "collision" in titles[0]
    assert titles[1].startswith("direction_velocity") and "reached in 34.5 s" in titles[1]
    fig = FIGURES["snapshots.png"](runs, field)
    assert len(fig.get_axes()) == 8
    fig = FIGURES["obstacle_distance.png"](runs, field)
    labels = [t.get_text() for t in fig.get_axes()[0].get_legend().get_texts()]
    assert "Obs 1" in labels and "Obs 2" in labels
    assert any("d_safe" in s for s in labels) and any("collision" in s for s in labels)
    # obstacle 4 (far below the path of the stalled run) is not shown for that run
    assert "Obs 4" not in labels
    assert "of 4" in fig.get_axes()[0].get_title()
    fig = FIGURES["trajectory_3d.png"](runs, field)
    assert len(fig.get_axes()) == 4


def test_colors_are_per_label(example):
    field, runs = example
    assert run_colors(runs) == run_colors(runs[::-1])
    colors = run_colors(runs + [make_run("custom", field, detour_path(field))])
    assert len(set(colors.values())) == 3


def test_outcome_texts(example):
    field, runs = example
    assert outcome(runs[0], field).startswith("collision at")
    assert outcome(runs[1], field) == "reached in 34.5 s"
    stalled = make_run("basic", field, stalled_path(field)[:40], stalled=1.0, collision=0.0, time_to_goal=math.nan)
    assert outcome(stalled, field).startswith("stalled, ")
    timeout = make_run("basic", field, stalled_path(field)[:10])  # no metrics at all
    assert outcome(timeout, field).startswith("not reached")


@pytest.mark.parametrize(
    "case",
    ["zero_obstacles", "single_run", "length_one", "stalled_only", "moving_only_vertically"],
)
def test_edge_cases_do_not_raise(case):
    field = make_field()
    if case == "zero_obstacles":
        field = make_field(0)
        runs = [make_run("basic", field, detour_path(field), time_to_goal=34.5),
                make_run("direction", field, stalled_path(field), time_to_goal=math.nan, stalled=1.0)]
        assert runs[0].clearance.shape == (70, 0)
    elif case == "single_run":
        runs = [make_run("direction_velocity", field, detour_path(field), time_to_goal=34.5)]
    elif case == "length_one":
        runs = [make_run("basic", field, detour_path(field)[:1], time_to_goal=math.nan),
                make_run("direction_velocity", field, detour_path(field)[:1])]
    elif case == "stalled_only":
        runs = [make_run("basic", field, stalled_path(field)[:40], stalled=1.0, time_to_goal=math.nan)]
    else:
        field = Field(start=field.start, goal=field.goal, obstacle_position=field.obstacle_position,
                      obstacle_velocity=np.tile([0.0, 0.0, 0.3], (4, 1)), obstacle_radius=field.obstacle_radius,
                      obstacle_cylinder=field.obstacle_cylinder, r_uav=0.3, r_goal=0.5, d_safe=1.0, title="")
        runs = [make_run("basic", field, detour_path(field), time_to_goal=34.5)]
    for name, make in FIGURES.items():
        fig = make(runs, field)
        check_figure(fig)
        # drawing is the slow part (~1 s a figure): draw only where it can fail (the x-y and 3-D
        # figures set fixed limits; a length-1 run has a zero-length time axis, zero obstacles an
        # empty clearance panel); test_plot_all_writes_pngs renders every figure
        if name in ("obstacle_distance.png", "goal_distance.png") and case in ("zero_obstacles", "length_one"):
            buf = io.BytesIO()
            fig.savefig(buf, format="png", dpi=30)
            assert buf.getvalue().startswith(b"\x89PNG")


def test_bad_shapes_are_rejected():
    field = make_field()
    with pytest.raises(ValueError, match="position"):
        Run(label="x", time=np.arange(3.0), position=np.zeros((2, 3)), velocity=np.zeros((3, 3)),
            clearance=np.zeros((3, 4)), goal_distance=np.zeros(3), metrics={})
    with pytest.raises(ValueError, match="no runs"):
        plot_all([], field, "/nonexistent")


def test_backend_left_alone(example):
    """Figures are pyplot-free ``Figure`` objects: rendering never switches the user's backend."""
    import matplotlib

    field, runs = example
    before = matplotlib.get_backend()
    buf = io.BytesIO()
    FIGURES["goal_distance.png"](runs, field).savefig(buf, format="png", dpi=30)
    assert buf.getvalue().startswith(b"\x89PNG")
    assert matplotlib.get_backend() == before


@pytest.mark.parametrize("n_runs", [1, 2])
@pytest.mark.parametrize("name", list(FIGURES))
def test_legends_fit_inside_the_figure(example, name, n_runs):
    """No legend is cut off at an edge (the report's gallery draws one run per figure)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    field, runs = example
    fig = FIGURES[name](runs[:n_runs], field)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    legends = figure_legends(fig) + [ax.get_legend() for ax in fig.get_axes() if ax.get_legend() is not None]
    for legend in legends:
        box = legend.get_window_extent(renderer)
        assert box.x0 >= -1 and box.x1 <= fig.bbox.width + 1, (name, box, fig.bbox.width)


@pytest.mark.parametrize("count", [1, 4, pytest.param(9, marks=pytest.mark.slow)])
def test_one_panel_per_run_figures_are_rows_of_three_that_fit_a_page(example, count, tmp_path):
    """Nine planners side by side (study 11's figure) used to make a 5,200 px strip: panels go into rows
    of three, every figure stays at most 2,400 px wide at plot_all's 130 dpi and at most 3:1."""
    from matplotlib.image import imread

    from jaxapf.simulate.figures import plot_obstacle_distance, plot_trajectories

    field, runs = example
    many = [dataclasses.replace(runs[i % 2], label=f"planner{i}") for i in range(count)]
    for plot in (plot_trajectories, plot_obstacle_distance):
        fig = plot(many, field)
        check_figure(fig)
        assert len(fig.get_axes()) == count
        fig.savefig(tmp_path / "f.png", dpi=130)
        height, width = imread(tmp_path / "f.png").shape[:2]
        assert width <= 2400 and width <= 3 * height, (plot.__name__, count, width, height)


def test_a_run_that_never_leaves_the_start_is_still_drawn(example):
    """A stall at the start (seen in a report's gallery) drew its path under the start marker, while
    the legend named it: the final position is a dot in the run's colour, above the start marker."""
    from matplotlib.colors import to_rgba

    from jaxapf.simulate.figures import plot_trajectories

    field, _ = example
    still = make_run("basic", field, np.repeat(field.start[None], 30, axis=0), success=0.0, collision=0.0,
                     stalled=1.0, time_to_goal=math.nan, final_distance=30.0)
    fig = plot_trajectories([still], field)
    color = to_rgba(run_colors([still])["basic"])
    dots = [line for line in fig.get_axes()[0].get_lines() if line.get_marker() == "o"
            and to_rgba(line.get_color()) == color and np.allclose(line.get_xydata()[-1], field.start[:2])]
    start_z = max(line.get_zorder() for line in fig.get_axes()[0].get_lines() if line.get_marker() == "s")
    assert dots and dots[0].get_zorder() > start_z


def test_nine_planners_side_by_side_get_nine_colours(example):
    from jaxapf.planners import PLANNERS

    field, runs = example
    labels = [*PLANNERS.names(), "basic+cbf", "direction_velocity+cbf"][:9]
    colors = run_colors([dataclasses.replace(runs[0], label=label) for label in labels])
    assert len(set(colors.values())) == len(labels), colors


def test_failure_cause_states_the_outcome_the_nearest_obstacle_and_a_bad_start():
    from jaxapf.simulate.figures import failure_cause, plot_failure

    field = make_field(2)
    # starts 0.2 m from obstacle 1's surface (centre 12, 1.5; radius 1.5 + r_uav 0.3), stays put: a stall
    start = np.array([12.0, 1.5 - 2.0, 5.0])
    field = Field(start=start, goal=field.goal, obstacle_position=field.obstacle_position[:1],
                  obstacle_velocity=field.obstacle_velocity[:1], obstacle_radius=field.obstacle_radius[:1],
                  obstacle_cylinder=field.obstacle_cylinder[:1], r_uav=0.3, r_goal=0.5, d_safe=1.0)
    path = np.stack([np.full(9, 12.0), np.linspace(-0.5, -0.9, 9), np.full(9, 5.0)], axis=1)
    why = failure_cause(make_run("basic", field, path, stalled=True, final_distance=18.0), field)
    assert why == ("stalled, 18.0 m from goal after flying 0.40 m; obstacle 1 nearest there (0.60 m from its "
                   "surface); a bad start: it began 0.20 m from obstacle 1, inside d_safe = 1 m")
    # a collision is seen at its first sample, and a start outside d_safe is no bad start
    path = np.stack([np.full(9, 12.0), np.linspace(-3.0, 1.0, 9), np.full(9, 5.0)], axis=1)  # 0.5 m a step
    why = failure_cause(make_run("basic", field, path, collision=True), field)
    assert why == "collision at 3.0 s after flying 3.00 m; obstacle 1 nearest there (-0.30 m from its surface)"
    fig = plot_failure(make_run("basic", field, path, collision=True), field, "title")
    assert [ax.get_ylabel() for ax in fig.axes] == ["y [m]", "clearance [m]"]
    # a state that turned non-finite (the invalid outcome): seen at its last finite sample, drawn, no error
    # (before: numpy's "All-NaN slice encountered" ended the report)
    path = np.stack([np.full(9, 12.0), np.linspace(-3.0, -1.0, 9), np.full(9, 5.0)], axis=1)
    path[6:] = np.nan
    run = make_run("nan", field, path, invalid=True, final_distance=float("nan"))
    assert failure_cause(run, field) == ("non-finite (invalid) at 3.0 s after flying 1.25 m; obstacle 1 nearest "
                                         "there (1.45 m from its surface)")
    fig = plot_failure(run, field, "title")
    assert [ax.get_ylabel() for ax in fig.axes] == ["y [m]", "clearance [m]"]

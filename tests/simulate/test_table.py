"""What ``jaxapf simulate`` prints: only the metrics of the components each run flies (``-`` where a run's
components do not measure one), and a note where a run stalled (on ``paper_static``, that the paper's
scenario 1 does not reproduce)."""

from __future__ import annotations

import types

from jaxapf.cli.commands import stall_notes
from jaxapf.config import SimConfig
from jaxapf.engine.components import metrics_in_use
from jaxapf.metrics import METRICS
from jaxapf.simulate import format_metrics_table

OWNED = {"vo_infeasible_steps", "vo_truncated_steps", "cbf_infeasible_steps", "cbf_truncated_steps", "max_tilt",
         "saturation_time", "unseen_steps", "kmpc_infeasible_steps"}


def test_a_metric_a_component_owns_is_in_use_only_where_that_component_flies():
    names = METRICS.names()
    assert set(names) - set(metrics_in_use(SimConfig.from_flat(method="basic"), names)) == OWNED
    vo = set(metrics_in_use(SimConfig.from_flat(method="velocity_obstacle_unilateral"), names))
    assert {"vo_infeasible_steps", "vo_truncated_steps"} <= vo and not {"cbf_infeasible_steps", "max_tilt"} & vo
    assert "kmpc_infeasible_steps" in metrics_in_use(SimConfig.from_flat(method="keepout_mpc"), names)
    filters = ("cbf", "robust_cbf", "braking_cbf")
    every_cbf = [set(metrics_in_use(SimConfig.from_flat(filter=f), names)) for f in filters]
    assert all({"cbf_infeasible_steps", "cbf_truncated_steps"} <= m for m in every_cbf)  # owned by all three
    quad = set(metrics_in_use(SimConfig.from_flat(plant="quadrotor", sensor="noisy"), names))
    assert {"max_tilt", "saturation_time", "unseen_steps"} <= quad


def test_the_table_shows_a_metric_some_run_measures_and_a_dash_where_another_does_not():
    runs = [types.SimpleNamespace(label="basic", metrics={"success": True, "min_clearance": 0.5}),
            types.SimpleNamespace(label="velocity_obstacle",
                                  metrics={"success": False, "min_clearance": 0.25, "vo_infeasible_steps": 3})]
    lines = format_metrics_table(runs).splitlines()
    assert lines[1].split() == ["success", "true", "false"]
    assert [line.split() for line in lines if line.startswith("vo_infeasible_steps")] == [
        ["vo_infeasible_steps", "-", "3"]]


def test_a_stalled_run_gets_a_note_and_paper_static_says_it_does_not_reproduce():
    stalled = types.SimpleNamespace(label="basic", metrics={"stalled": True, "final_distance": 12.66})
    arrived = types.SimpleNamespace(label="vortex", metrics={"stalled": False, "final_distance": 0.3})
    notes = stall_notes("trap", [stalled, arrived])
    assert notes == ["note: basic stalled 12.7 m from the goal: it stopped making progress in a local minimum of "
                     "its potential field (metric `stalled`)"]
    assert "does not reproduce" in stall_notes("paper_static", [stalled])[-1]
    assert stall_notes("paper_static", [arrived]) == []

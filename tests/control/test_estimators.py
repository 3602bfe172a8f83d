"""Offset-free tracking (jaxapf.control.estimators) and the robust CBF, against control theory: the
estimators' error dynamics as designed, zero steady-state offset under a constant wind, and the robust
condition keeping the UAV off an obstacle that the worst admissible push, constant or a step, drives
it toward."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf import Gains
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.control import ESTIMATORS, Integral, Observer
from jaxapf.engine import rollout, rollout_metrics

vectors = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3)


def _flight(d, commands, dt):
    """States ``[p, v]`` of the exact double integrator pushed by a constant ``d`` under ``commands``."""
    x = [np.zeros(6)]
    for u in commands:
        p, v = x[-1][:3], x[-1][3:]
        a = u + d
        x.append(np.concatenate([p + dt * v + 0.5 * dt * dt * a, v + dt * a]))
    return x


@pytest.mark.parametrize("estimator, gain, alpha", [
    (Observer(), {"dob_tau": 0.7}, lambda dt: 1.0 - math.exp(-dt / 0.7)),
    (Integral(), {"dob_ki": 30.0}, lambda dt: 30.0 * dt * dt / 2.0),
])
@given(d=vectors, dt=st.sampled_from([0.05, 0.1, 0.2]), seed=st.integers(0, 1000))
@settings(max_examples=25, deadline=None)
def test_the_estimate_error_decays_geometrically_as_designed(estimator, gain, alpha, d, dt, seed):
    """For the double integrator and a constant push ``d``, ``d - d̂_k = (1 - α)^k d`` whatever the
    commands: α = 1 - exp(-Δt/τ) for the observer, k_i Δt²/2 for the integral action."""
    d = np.asarray(d)
    commands = np.random.default_rng(seed).uniform(-3, 3, (12, 3))
    states = _flight(d, commands, dt)
    gains = Gains(**gain)
    with jax.enable_x64(True):
        estimate = jnp.zeros(3)
        for k in range(1, len(states)):
            estimate = estimator.update(jnp.asarray(states[k - 1]), jnp.asarray(commands[k - 1]), estimate,
                                        jnp.asarray(states[k]), gains.as_arrays(jnp.float64), dt)
            np.testing.assert_allclose(d - np.asarray(estimate), (1.0 - alpha(dt)) ** k * d, atol=1e-9)


def _steady(plant: str, estimator: str) -> float:
    """Distance to the goal after 60 s of flight on a free line with a steady 6 m/s cross wind
    (r_goal 1 cm, so the episode does not end at the goal)."""
    scenario = one_obstacle_scenario(10.0, 5.0, 0.5)
    scenario = dataclasses.replace(scenario, obstacles=dataclasses.replace(scenario.obstacles,
                                                                           valid=jnp.asarray([False])))
    sim = SimConfig.from_flat(method="basic", plant=plant, disturbance="wind", estimator=estimator, t_max=60.0,
                              r_goal=0.01)
    traj = jax.jit(rollout, static_argnums=(2, 3))(scenario, Gains(wind_speed=6.0, wind_heading=90.0), sim,
                                                  MPCConfig(horizon=10, iters=20))
    return float(jnp.linalg.norm(traj.position[-1] - scenario.goal))


@pytest.mark.slow
@pytest.mark.parametrize("plant", ["double_integrator", "quadrotor"])
def test_offset_free_tracking_reaches_the_goal_in_a_steady_wind(plant):
    """Without an estimator a steady cross wind holds the UAV off its goal (the potential's pull balances
    the push); with either estimator the steady state has no offset (offset-free MPC: at rest at the
    goal the plan is a = 0 and the command -d̂ = -d)."""
    assert _steady(plant, "none") > 0.3
    assert _steady(plant, "observer") < 0.02
    assert _steady(plant, "integral") < 0.02


def _beside(offset: float, heading: float, speed: float, margin: float) -> dict[str, dict]:
    """A repulsion-free flight toward a cylinder ``offset`` m beside its line, in a steady wind of
    ``speed`` m/s toward ``heading``: the metrics with the plain and the robust CBF (``cbf_margin``)."""
    scenario = one_obstacle_scenario(16.0, 8.0, 1.0)
    scenario = dataclasses.replace(scenario, obstacles=dataclasses.replace(
        scenario.obstacles, position=jnp.asarray([[8.0, offset, 2.0]])))
    gains = Gains(k_rep=1e-6, wind_speed=speed, wind_heading=heading, cbf_margin=margin)
    return {name: rollout_metrics(scenario, gains, SimConfig.from_flat(
        method="basic", filter=name, disturbance="wind", t_max=20.0), MPCConfig(horizon=10, iters=20))
        for name in ("cbf", "robust_cbf", "braking_cbf")}


@pytest.mark.slow
@pytest.mark.parametrize("offset", [0.0, 0.5])
def test_the_robust_cbf_keeps_off_an_obstacle_the_push_drives_toward(offset):
    """A steady 6 m/s wind pushes the UAV toward the cylinder with 1.8 m/s² (drag 0.3): the plain CBF,
    blind to the push, lets it in; the robust CBFs (exponential and braking) with cbf_margin = 1.8 keep
    every interval clear, with no infeasible step."""
    out = _beside(offset, 30.0, 6.0, 1.8)
    assert float(out["cbf"]["min_clearance"]) < 0.0
    for name in ("robust_cbf", "braking_cbf"):
        assert float(out[name]["min_clearance"]) > 0.0
        assert int(out[name]["cbf_infeasible_steps"]) == 0


_STEP = """
import dataclasses, json, sys
import jax.numpy as jnp
sys.path.insert(0, {tests!r})
from conftest import one_obstacle_scenario
from jaxapf import Gains
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.engine import rollout_metrics
from jaxapf.world import Disturbance, register_disturbance

@dataclasses.dataclass(frozen=True)
class Step(Disturbance):
    \"\"\"1.8 m/s² toward 30° from t = 2 s on.\"\"\"
    def init(self, scenario, gains, sim):
        return ()
    def __call__(self, state, k, scenario, gains, sim):
        on = (k * sim.episode.dt >= 2.0).astype(scenario.start.dtype)
        return on * 1.8 * jnp.asarray([0.8660254, 0.5, 0.0], scenario.start.dtype), state

register_disturbance("step_push", Step())
out = {{}}
for offset in (0.0, 0.5):
    sc = one_obstacle_scenario(16.0, 8.0, 1.0)
    sc = dataclasses.replace(sc, obstacles=dataclasses.replace(sc.obstacles,
                                                               position=jnp.asarray([[8.0, offset, 2.0]])))
    for f in ("cbf", "robust_cbf", "braking_cbf"):
        sim = SimConfig.from_flat(method="basic", filter=f, disturbance="step_push", t_max=20.0)
        m = rollout_metrics(sc, Gains(k_rep=1e-6, cbf_margin=1.8), sim, MPCConfig(horizon=10, iters=20))
        out[f"{{offset}} {{f}}"] = [float(m["min_clearance"]), int(m["cbf_infeasible_steps"])]
print(json.dumps(out))
"""


@pytest.mark.slow
def test_the_robust_cbf_holds_against_a_step_push():
    """The push of 1.8 m/s² toward the cylinder switches on at t = 2 s (a disturbance of this test, in a
    second process): the plain CBF lets the UAV in, the robust ones told δ = 1.8 keep it clear."""
    import json
    import subprocess
    import sys

    from conftest import ROOT

    out = json.loads(subprocess.run([sys.executable, "-c", _STEP.format(tests=str(ROOT / "tests"))],
                                    capture_output=True, text=True, check=True).stdout)
    for offset in ("0.0", "0.5"):
        assert out[f"{offset} cbf"][0] < 0.0
        for f in ("robust_cbf", "braking_cbf"):
            assert out[f"{offset} {f}"][0] > 0.0 and out[f"{offset} {f}"][1] == 0


@pytest.mark.slow
def test_the_robust_cbf_reports_where_the_box_cannot_absorb_the_push():
    """A 2.7 m/s² tailwind straight at the cylinder leaves the 3 m/s² box too little to brake against
    it: the robust condition cannot hold and the steps are counted (cbf_infeasible_steps)."""
    assert int(_beside(0.0, 0.0, 9.0, 2.7)["robust_cbf"]["cbf_infeasible_steps"]) > 0


def test_no_estimator_is_the_default_and_compiles_nothing_in():
    assert SimConfig().planner.estimator == "none" and not ESTIMATORS.get("none").active
    assert [g.name for g in ESTIMATORS.get("observer").gains] == ["dob_tau"]

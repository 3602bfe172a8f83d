"""The CBF safety filter: its constraints against an independent numpy computation and the closed
loop it protects (its QP: tests/test_projection.py)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.control import FILTERS, cbf_constraints
from jaxapf.datatypes import Obstacles
from jaxapf.gains import Gains
from jaxapf.rollout import rollout_metrics


def _obstacles(rng: np.random.Generator, m: int, valid: int) -> Obstacles:
    return Obstacles(position=jnp.asarray(rng.uniform(-6, 6, (m, 3)), jnp.float32),
                     velocity=jnp.asarray(rng.uniform(-1, 1, (m, 3)), jnp.float32),
                     radius=jnp.asarray(rng.uniform(0.3, 1.0, m), jnp.float32),
                     cylinder=jnp.asarray(rng.random(m) < 0.5),
                     valid=jnp.arange(m) < valid)


@given(seed=st.integers(0, 2**31 - 1), k0=st.floats(0.0, 4.0), k1=st.floats(0.0, 4.0))
@settings(max_examples=25, deadline=None)
def test_constraints_are_the_exponential_cbf_condition(seed, k0, k1):
    """``g·a - b`` (unscaled) equals ``ḧ + k1 ḣ + k0 h`` computed in float64 numpy, for any ``a``."""
    rng = np.random.default_rng(seed)
    obs = _obstacles(rng, 4, 3)
    x = rng.uniform(-3, 3, 6).astype(np.float32)
    t, a = np.float32(rng.uniform(0, 5)), rng.uniform(-3, 3, 3)
    sim = SimConfig()
    g, b = cbf_constraints(jnp.asarray(x), t, obs.columns(), Gains(cbf_k0=k0, cbf_k1=k1), sim)
    g, b = np.asarray(g, np.float64), np.asarray(b, np.float64)
    for o in range(3):
        keep = np.array([1.0, 1.0, 0.0 if bool(obs.cylinder[o]) else 1.0])
        r = keep * (x[:3] - (np.asarray(obs.position[o], np.float64) + np.asarray(obs.velocity[o], np.float64) * t))
        w = keep * (x[3:] - np.asarray(obs.velocity[o], np.float64))
        big_r = float(obs.radius[o]) + sim.vehicle.r_uav
        h, hd, hdd = r @ r - big_r**2, 2 * r @ w, 2 * w @ w + 2 * r @ a
        scale = 2 * np.linalg.norm(r)
        assert (g[o] @ a - b[o]) * scale == pytest.approx(hdd + k1 * hd + k0 * h, rel=1e-4, abs=1e-3)
        assert np.linalg.norm(g[o]) == pytest.approx(1.0, abs=1e-5)
    assert np.all(g[3] == 0) and b[3] == -1.0  # padded slot: 0 >= -1 always holds


def test_the_filter_keeps_a_repulsion_free_flight_off_the_obstacle():
    """Without repulsion (k_rep = 0) the MPC flies straight through the cylinder on the start–goal
    line; with ``filter = "cbf"`` the same flight stays clear of it, and no step is infeasible."""
    scenario = one_obstacle_scenario(16.0, 8.0, 1.0)
    base = SimConfig.from_flat(method="basic", t_max=20.0)
    gains = Gains(k_rep=1e-6)
    mpc = MPCConfig(horizon=10, iters=20)
    bare = rollout_metrics(scenario, gains, base, mpc)
    safe = rollout_metrics(scenario, gains, dataclasses.replace(base, planner=dataclasses.replace(
        base.planner, filter="cbf")), mpc)
    assert bool(bare["collision"])
    assert not bool(safe["collision"]) and float(safe["min_clearance"]) > 0.0
    assert int(safe["cbf_infeasible_steps"]) == 0 and int(bare["cbf_infeasible_steps"]) == 0
    assert FILTERS.get("cbf", "filter").gains[0].name == "cbf_k0"

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
from jaxapf.control import FILTERS, braking_constraints, cbf_coefficients, cbf_constraints
from jaxapf.datatypes import Obstacles
from jaxapf.engine import rollout_metrics
from jaxapf.gains import Gains, gains_from_mapping
from jaxapf.projection import INFEASIBLE_TOL, nearest_feasible
from jaxapf.validation import ConfigError


def _obstacles(rng: np.random.Generator, m: int, valid: int) -> Obstacles:
    return Obstacles(position=jnp.asarray(rng.uniform(-6, 6, (m, 3)), jnp.float32),
                     velocity=jnp.asarray(rng.uniform(-1, 1, (m, 3)), jnp.float32),
                     radius=jnp.asarray(rng.uniform(0.3, 1.0, m), jnp.float32),
                     cylinder=jnp.asarray(rng.random(m) < 0.5),
                     valid=jnp.arange(m) < valid)


@given(seed=st.integers(0, 2**31 - 1), p1=st.floats(0.05, 4.0), p2=st.floats(0.05, 4.0))
@settings(max_examples=25, deadline=None)
def test_constraints_are_the_exponential_cbf_condition(seed, p1, p2):
    """``g·a - b`` (unscaled) equals ``ḧ + k1 ḣ + k0 h`` with ``k1 = p1 + p2``, ``k0 = p1 p2``, computed
    in float64 numpy, for any ``a``."""
    k0, k1 = p1 * p2, p1 + p2
    rng = np.random.default_rng(seed)
    obs = _obstacles(rng, 4, 3)
    x = rng.uniform(-3, 3, 6).astype(np.float32)
    t, a = np.float32(rng.uniform(0, 5)), rng.uniform(-3, 3, 3)
    sim = SimConfig()
    g, b = cbf_constraints(jnp.asarray(x), t, obs.columns(), Gains(cbf_p1=p1, cbf_p2=p2), sim)
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


@pytest.mark.slow
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
    assert [g.name for g in FILTERS.get("cbf", "filter").gains] == ["cbf_p1", "cbf_p2"]


def test_the_coefficients_are_the_sum_and_product_of_the_rates():
    """Hand-made: p1 = 2, p2 = 3 give k1 = 5, k0 = 6; the defaults p1 = p2 = 1 are the former
    k0 = 1, k1 = 2."""
    k0, k1 = cbf_coefficients(Gains(cbf_p1=2.0, cbf_p2=3.0))
    assert (float(k0), float(k1)) == (6.0, 5.0)
    k0, k1 = cbf_coefficients(Gains())
    assert (float(k0), float(k1)) == (1.0, 2.0)


@given(p1=st.floats(1e-3, 1e3), p2=st.floats(1e-3, 1e3))
@settings(max_examples=200, deadline=None)
def test_any_positive_rates_give_real_negative_roots(p1, p2):
    """Every setting is inside the exponential-CBF guarantee: s² + k1 s + k0 has the real negative
    roots -p1, -p2 (the discriminant (p1 - p2)² >= 0 up to rounding)."""
    k0, k1 = cbf_coefficients(Gains.unchecked({"cbf_p1": p1, "cbf_p2": p2}))
    roots = np.roots([1.0, k1, k0])
    assert np.all(np.abs(roots.imag) <= 1e-6 * k1)
    assert np.all(roots.real < 0)
    assert np.sort(roots.real) == pytest.approx(np.sort([-p1, -p2]), rel=1e-6, abs=1e-9 * k1)
    assert k1 * k1 - 4.0 * k0 >= -1e-12 * k1 * k1


@pytest.mark.parametrize("name", ["cbf_p1", "cbf_p2"])
@pytest.mark.parametrize("value", [0.0, -0.5])
def test_non_positive_rates_are_rejected_naming_the_field(name, value):
    with pytest.raises(ConfigError) as err:
        Gains(**{name: value})
    assert str(err.value) == f"gains.{name} = {value!r} is out of range; allowed: a finite number > 0"
    with pytest.raises(ConfigError, match=f"^run.toml:gains.{name} = "):
        gains_from_mapping({name: value}, where="run.toml:gains")


def _h_braking(p, v, t, obs, o, beta, lam, sim) -> float:
    """h_b = ḋ + φ(d) of obstacle ``o`` in float64 numpy (module docstring of jaxapf.control.cbf)."""
    keep = np.array([1.0, 1.0, 0.0 if bool(obs.cylinder[o]) else 1.0])
    r = keep * (p - (np.asarray(obs.position[o], np.float64) + np.asarray(obs.velocity[o], np.float64) * t))
    w = keep * (v - np.asarray(obs.velocity[o], np.float64))
    d = np.linalg.norm(r) - float(obs.radius[o]) - sim.vehicle.r_uav - 0.5 * sim.vehicle.a_max * sim.episode.dt ** 2
    phi = lam * d if lam * lam * d < 2 * beta else np.sqrt(2 * beta * d)
    return r @ w / np.linalg.norm(r) + phi, d


@given(seed=st.integers(0, 2**31 - 1), alpha=st.floats(0.1, 5.0), brake=st.floats(0.05, 0.5),
       margin=st.floats(0.0, 2.5))
@settings(max_examples=40, deadline=None)
def test_braking_rows_are_the_braking_condition(seed, alpha, brake, margin):
    """``g·a - b`` equals ``ḣ_b + α h_b - δ``, with ``ḣ_b`` a central finite difference of ``h_b`` along
    the motion under ``a`` (float64 numpy), for any state off the kink of ``φ``."""
    rng = np.random.default_rng(seed)
    obs = _obstacles(rng, 3, 2)
    sim = SimConfig()
    beta, lam = brake * (sim.vehicle.a_max - margin), 0.5 / sim.episode.dt
    x = rng.uniform(-3, 3, 6)
    t, a = rng.uniform(0, 5), rng.uniform(-3, 3, 3)
    g, b = braking_constraints(jnp.asarray(x, jnp.float32), jnp.float32(t), obs.columns(),
                               Gains(cbf_alpha=alpha, cbf_brake=brake, cbf_margin=margin), sim)
    g, b = np.asarray(g, np.float64), np.asarray(b, np.float64)
    eps = 1e-4
    for o in range(2):
        h, d = _h_braking(x[:3], x[3:], t, obs, o, beta, lam, sim)
        if d < 0.05 or abs(lam * lam * d - 2 * beta) < 0.05 * lam * lam:
            continue  # inside the obstacle, or at φ's kink where the difference straddles two pieces
        ahead, _ = _h_braking(x[:3] + x[3:] * eps + 0.5 * a * eps**2, x[3:] + a * eps, t + eps, obs, o, beta, lam, sim)
        behind, _ = _h_braking(x[:3] - x[3:] * eps + 0.5 * a * eps**2, x[3:] - a * eps, t - eps, obs, o, beta, lam, sim)
        assert g[o] @ a - b[o] == pytest.approx((ahead - behind) / (2 * eps) + alpha * h - margin, rel=2e-3, abs=2e-3)
        assert np.linalg.norm(g[o]) == pytest.approx(1.0, abs=1e-5)
    assert np.all(g[2] == 0) and b[2] == -1.0


@given(seed=st.integers(0, 2**31 - 1), brake=st.floats(0.05, 0.5), margin=st.floats(0.0, 2.9),
       gap=st.floats(0.0, 20.0), tangential=st.floats(-6.0, 6.0), speed=st.floats(0.0, 6.0))
@settings(max_examples=200, deadline=None)
def test_one_obstacle_never_makes_a_braking_step_infeasible_from_the_boundary(seed, brake, margin, gap,
                                                                             tangential, speed):
    """On the boundary ``h_b = 0`` of one obstacle (any distance, closing speed the barrier allows,
    any sideways speed, any obstacle velocity and δ < a_max) the condition and the box hold together:
    the filter's QP reports no violation."""
    rng = np.random.default_rng(seed)
    sim = SimConfig()
    beta, lam = brake * (sim.vehicle.a_max - margin), 0.5 / sim.episode.dt
    big_r = 0.7 + sim.vehicle.r_uav
    d = gap
    phi = lam * d if lam * lam * d < 2 * beta else np.sqrt(2 * beta * d)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    side = np.cross(direction, rng.normal(size=3))
    side /= np.linalg.norm(side)
    v_o = rng.normal(size=3) * speed / np.sqrt(3)
    p = direction * (big_r + 0.5 * sim.vehicle.a_max * sim.episode.dt ** 2 + d)  # obstacle at the origin
    v = v_o - phi * direction + tangential * side  # ḋ = -φ(d): on the boundary
    obs = Obstacles(position=jnp.zeros((1, 3)), velocity=jnp.asarray([v_o], jnp.float32), radius=jnp.asarray([0.7]),
                    cylinder=jnp.asarray([False]), valid=jnp.asarray([True]))
    g, b = braking_constraints(jnp.asarray(np.concatenate([p, v]), jnp.float32), jnp.float32(0.0), obs.columns(),
                               Gains(cbf_brake=brake, cbf_margin=margin), sim)
    _, worst, _ = nearest_feasible(jnp.asarray(rng.uniform(-3, 3, 3), jnp.float32), g, b, sim.vehicle.a_max, "box")
    assert float(worst) <= INFEASIBLE_TOL


def _chase(x0: float, velocity: float, heading: float, wind: float, margin: float) -> dict[str, dict]:
    """A repulsion-free flight along x with a cylinder starting at ``x0`` on the line and moving along
    it at ``velocity``, in a steady wind toward ``heading``: the metrics per CBF filter."""
    scenario = one_obstacle_scenario(16.0, 6.0, 1.0)
    scenario = dataclasses.replace(scenario, obstacles=dataclasses.replace(
        scenario.obstacles, position=jnp.asarray([[x0, 0.0, 2.0]]), velocity=jnp.asarray([[velocity, 0.0, 0.0]])))
    gains = Gains(k_rep=1e-6, cbf_margin=margin, wind_speed=wind, wind_heading=heading)
    return {name: rollout_metrics(scenario, gains, SimConfig.from_flat(
        method="basic", filter=name, disturbance="wind", t_max=20.0), MPCConfig(horizon=10, iters=20))
        for name in ("cbf", "braking_cbf")}


@pytest.mark.slow
def test_the_braking_cbf_flees_a_head_on_obstacle_against_the_push():
    """A cylinder comes head-on at 4 m/s while a 6 m/s wind pushes the UAV toward it with 1.8 m/s²:
    the exponential CBF is run down; the braking CBF told δ = 1.8 backs off at the obstacle's speed and
    stays clear, with no infeasible step (from a safe start one obstacle never makes a step
    infeasible)."""
    out = _chase(20.0, -4.0, 0.0, 6.0, 1.8)
    assert float(out["cbf"]["min_clearance"]) < 0.0
    assert float(out["braking_cbf"]["min_clearance"]) >= 0.0
    assert int(out["braking_cbf"]["cbf_infeasible_steps"]) == 0


@pytest.mark.slow
def test_the_braking_cbf_stays_ahead_of_an_obstacle_overtaking_from_behind():
    """A cylinder runs the UAV down from 6 m behind at 4 m/s in calm air (δ = 0): the braking CBF keeps it
    clear with every step feasible and the UAV still reaches its goal."""
    out = _chase(-6.0, 4.0, 0.0, 0.0, 0.0)["braking_cbf"]
    assert float(out["min_clearance"]) >= 0.0 and int(out["cbf_infeasible_steps"]) == 0 and bool(out["success"])

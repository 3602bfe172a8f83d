"""Potentials and forces (SPEC 3): finite differences, masks, the paper's formulas, true bounds."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.config import CONVENTIONS
from jaxapf.datatypes import Obstacles
from jaxapf.gains import Gains
from jaxapf.planners import APF, PLANNERS
from jaxapf.planners.potentials import (
    repulsive_force,
    total_force,
    total_potential,
    weight,
    weight_bounds,
    weighted_repulsive_potential,
)
from jaxapf.validation import ConfigError

GAINS = dict(k_rep=3.0, d_s=4.0, gamma=1.5, k=0.7)
#: The paper's three weights under both sign conventions.
VARIANTS = [(m, c) for m in ("basic", "direction", "direction_velocity") for c in CONVENTIONS]


@partial(jax.jit, static_argnames=("method", "convention", "cylinder"))
def _u_and_f(p, v, p_o, v_o, radius, *, method, convention, cylinder):
    kw = dict(GAINS, method=method, convention=convention, radius=radius, cylinder=cylinder)
    return weighted_repulsive_potential(p, v, p_o, v_o, **kw), repulsive_force(p, v, p_o, v_o, **kw)


def _random_case(rng, cylinder):
    """A UAV inside the influence region (clearance in [0.3, 3.5]) of an obstacle of radius 0.8."""
    p_o = rng.normal(size=3)
    direction = rng.normal(size=3)
    if cylinder:
        direction[2] = 0.0
    direction /= np.linalg.norm(direction)
    p = p_o + direction * (0.8 + rng.uniform(0.3, 3.5))
    if cylinder:
        p[2] += rng.normal() * 3.0  # height is irrelevant to a cylinder
    return p, rng.normal(size=3) * 1.5, p_o, rng.normal(size=3)


@pytest.mark.parametrize("cylinder", [False, True])
@pytest.mark.parametrize("method,convention", VARIANTS)
def test_force_matches_central_differences_float64(method, convention, cylinder):
    rng = np.random.default_rng(hash((method, convention, cylinder)) % 2**32)
    h = 1e-6
    with jax.enable_x64(True):
        for _ in range(5):
            p, v, p_o, v_o = (jnp.asarray(a, jnp.float64) for a in _random_case(rng, cylinder))
            run = partial(_u_and_f, method=method, convention=convention, cylinder=cylinder)
            _, force = run(p, v, p_o, v_o, 0.8)
            fd = np.array([
                (run(p + h * e, v, p_o, v_o, 0.8)[0] - run(p - h * e, v, p_o, v_o, 0.8)[0]) / (2 * h)
                for e in jnp.eye(3)
            ])
            np.testing.assert_allclose(np.asarray(force), -fd, rtol=1e-6, atol=1e-8)


def test_weight_gradient_term_is_present_and_sideways():
    """F* = -(ω∇U + U∇ω): the second term is not along the line of sight."""
    p, v, p_o, v_o = jnp.zeros(3), jnp.array([1.0, 1.0, 0.0]), jnp.array([2.0, 0.0, 0.0]), jnp.zeros(3)
    _, force = _u_and_f(p, v, p_o, v_o, 0.5, method="direction_velocity", convention="intent", cylinder=False)
    assert abs(float(force[1])) > 1e-3  # a classical force would be along -x only
    # and it is exactly what ω∇U + U∇ω gives when ω is held fixed in one of the two terms
    kw = dict(GAINS, method="direction_velocity", convention="intent", radius=0.5)
    w = weight(p, v, p_o, v_o, gamma=GAINS["gamma"], k=GAINS["k"], method="direction_velocity", convention="intent")
    base = weighted_repulsive_potential(p, v, p_o, v_o, **dict(kw, method="basic"))
    grad_base = jax.grad(lambda q: weighted_repulsive_potential(q, v, p_o, v_o, **dict(kw, method="basic")))(p)
    grad_w = jax.grad(lambda q: weight(q, v, p_o, v_o, gamma=GAINS["gamma"], k=GAINS["k"],
                                       method="direction_velocity", convention="intent"))(p)
    np.testing.assert_allclose(force, -(w * grad_base + base * grad_w), rtol=1e-5)


@pytest.mark.parametrize("method,convention", VARIANTS)
def test_zero_outside_influence_distance(method, convention):
    p, p_o = jnp.array([5.0, 0.0, 0.0]), jnp.zeros(3)
    u, f = _u_and_f(p, jnp.ones(3), p_o, jnp.ones(3), 0.5, method=method, convention=convention, cylinder=False)
    assert float(u) == 0.0 and np.all(np.asarray(f) == 0.0)


def test_force_inside_collision_is_finite_and_points_out():
    p, p_o = jnp.array([0.3, 0.0, 0.0]), jnp.zeros(3)  # 0.7 m deep inside a 1 m sphere
    u, f = _u_and_f(p, jnp.zeros(3), p_o, jnp.zeros(3), 1.0, method="basic", convention="intent", cylinder=False)
    assert np.isfinite(float(u)) and np.all(np.isfinite(np.asarray(f)))
    assert float(f[0]) > 0.0


def test_literal_reproduces_paper_formulas_term_by_term():
    rng = np.random.default_rng(3)
    gamma, k, k_rep, d_s, radius, eps = 1.5, 0.7, 3.0, 4.0, 0.8, 1e-3
    with jax.enable_x64(True):
        for _ in range(20):
            p, v, p_o, v_o = _random_case(rng, cylinder=False)
            r_e = p - p_o                                   # paper: r_e = p - p_o
            cos_theta = v @ r_e / (np.sqrt(v @ v + eps**2) * np.linalg.norm(r_e))
            g = (v - v_o) @ r_e / np.linalg.norm(r_e)       # paper: G = v_e · r̂_e
            omega = (1 + gamma * (1 + cos_theta) / 2) * (2 + k * np.tanh(g))  # eq. 19
            d = np.linalg.norm(r_e) - radius
            u_rep = 0.5 * k_rep * (1 / d - 1 / d_s) ** 2 if d <= d_s else 0.0  # eq. 13
            got = weighted_repulsive_potential(
                *(jnp.asarray(a) for a in (p, v, p_o, v_o)), k_rep=k_rep, d_s=d_s, gamma=gamma, k=k,
                method="direction_velocity", convention="literal", radius=radius, eps_v=eps)
            np.testing.assert_allclose(float(got), omega * u_rep, rtol=1e-12)


def test_intent_flips_both_signs_of_literal():
    p, v, p_o, v_o = jnp.zeros(3), jnp.array([1.0, 0.0, 0.0]), jnp.array([2.0, 0.0, 0.0]), jnp.array([-1.0, 0, 0])
    kw = dict(gamma=1.0, k=0.5, method="direction_velocity")
    # obstacle ahead and approaching: intent gives the maximum (1+γ)(2+k tanh 2), literal the minimum
    assert float(weight(p, v, p_o, v_o, convention="intent", **kw)) == pytest.approx(
        2.0 * (2 + 0.5 * np.tanh(2.0)), rel=1e-5)
    assert float(weight(p, v, p_o, v_o, convention="literal", **kw)) == pytest.approx(
        1.0 * (2 - 0.5 * np.tanh(2.0)), rel=1e-5)


def test_hovering_uav_has_cos_theta_zero():
    w = weight(jnp.zeros(3), jnp.zeros(3), jnp.ones(3), jnp.zeros(3), gamma=2.0, k=0.0,
               method="direction", convention="intent")
    assert float(w) == pytest.approx(2.0)  # 1 + γ (1 + 0) / 2


vec3 = st.lists(st.floats(-5, 5), min_size=3, max_size=3).map(np.array)


@settings(max_examples=60, deadline=None)
@given(p=vec3, v=vec3, p_o=vec3, v_o=vec3, gamma=st.floats(0, 5), k=st.floats(0, 4),
       method=st.sampled_from(["direction", "direction_velocity"]), convention=st.sampled_from(CONVENTIONS))
def test_weight_true_bounds(p, v, p_o, v_o, gamma, k, method, convention):
    w = float(_weight_jit(p, v, p_o, v_o, gamma, k, method=method, convention=convention))
    lo, hi = (float(b) for b in weight_bounds(method, gamma=jnp.float32(gamma), k=jnp.float32(k)))
    assert lo - 1e-4 * (1 + abs(lo)) <= w <= hi + 1e-4 * hi
    if method == "direction_velocity" and k <= 1.0:
        assert w >= 1.0 - 1e-5  # the paper's lower bound, true only for k <= 1


@partial(jax.jit, static_argnames=("method", "convention"))
def _weight_jit(p, v, p_o, v_o, gamma, k, *, method, convention):
    return weight(jnp.asarray(p, jnp.float32), jnp.asarray(v, jnp.float32), jnp.asarray(p_o, jnp.float32),
                  jnp.asarray(v_o, jnp.float32), gamma=gamma, k=k, method=method, convention=convention)


def test_paper_lower_bound_fails_for_k_above_one():
    """A receding obstacle straight behind: ω = 1 · (2 - k tanh c) -> 2 - k < 1 for k > 1."""
    w = weight(jnp.zeros(3), jnp.array([5.0, 0, 0]), jnp.array([-2.0, 0, 0]), jnp.zeros(3),
               gamma=1.0, k=1.8, method="direction_velocity", convention="intent")
    assert float(w) < 1.0
    assert float(w) == pytest.approx(2 - 1.8 * np.tanh(5.0), rel=1e-5)


def _field(valid_extra: bool):
    """One real obstacle and two padded slots, one of them placed right next to the UAV."""
    return Obstacles(
        position=jnp.array([[2.0, 0.5, 0.0], [0.6, 0.0, 0.0], [1e6, 1e6, 1e6]]),
        velocity=jnp.array([[0.0, -0.3, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
        radius=jnp.array([0.7, 0.2, 0.0]),
        cylinder=jnp.array([False, True, False]),
        valid=jnp.array([True, valid_extra, False]),
    )


@pytest.mark.slow
def test_padded_slots_contribute_exactly_nothing():
    p, v, goal = jnp.zeros(3), jnp.array([1.0, 0.0, 0.0]), jnp.array([10.0, 0.0, 0.0])
    kw = dict(method="direction_velocity", convention="intent", r_uav=0.3)
    one = Obstacles(*(leaf[:1] for leaf in jax.tree_util.tree_leaves(_field(False))))
    ref_u = total_potential(p, v, 0.5, goal, one, Gains(), **kw)
    ref_f = total_force(p, v, 0.5, goal, one, Gains(), **kw)
    padded = _field(False)
    assert float(total_potential(p, v, 0.5, goal, padded, Gains(), **kw)) == float(ref_u)
    np.testing.assert_array_equal(total_force(p, v, 0.5, goal, padded, Gains(), **kw), ref_f)
    # and the near slot does matter once it is valid, so the test could fail
    assert float(total_potential(p, v, 0.5, goal, _field(True), Gains(), **kw)) != float(ref_u)


def test_unknown_method_is_a_clear_error():
    with pytest.raises(ConfigError, match="method = 'magic' is not a registered planner"):
        weighted_repulsive_potential(jnp.zeros(3), jnp.zeros(3), jnp.ones(3), jnp.zeros(3), k_rep=1.0,
                                     d_s=2.0, gamma=0.0, k=0.0, method="magic")
    with pytest.raises(ConfigError, match="'velocity_obstacle' is not a potential-field planner.*direction_velocity"):
        weighted_repulsive_potential(jnp.zeros(3), jnp.zeros(3), jnp.ones(3), jnp.zeros(3), k_rep=1.0,
                                     d_s=2.0, gamma=0.0, k=0.0, method="velocity_obstacle")


@pytest.mark.parametrize("method,convention", VARIANTS)
def test_total_force_is_the_gradient_of_the_field_and_the_sum_of_its_obstacles(method, convention):
    """The field force equals central differences of the total potential and
    the attractive force plus the single-obstacle ``repulsive_force`` of each valid obstacle."""
    kw = dict(method=method, convention=convention, r_uav=0.3)
    gains = Gains(k_rep=3.0, d_s=4.0, gamma=1.5, k=0.7)
    h = 1e-6
    with jax.enable_x64(True):
        field = jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float64) if a.dtype.kind == "f" else a,
                                       _field(True))
        p, v, goal, t = jnp.array([0.2, -0.4, 0.3]), jnp.array([1.0, 0.2, -0.1]), jnp.array([10.0, 0.0, 0.0]), 0.5
        force = total_force(p, v, t, goal, field, gains, **kw)
        fd = np.array([(total_potential(p + h * e, v, t, goal, field, gains, **kw)
                        - total_potential(p - h * e, v, t, goal, field, gains, **kw)) / (2 * h) for e in jnp.eye(3)])
        np.testing.assert_allclose(force, -fd, rtol=1e-6, atol=1e-8)
        per_obstacle = [
            repulsive_force(p, v, field.position[i] + t * field.velocity[i], field.velocity[i], k_rep=gains.k_rep,
                            d_s=gains.d_s, gamma=gains.gamma, k=gains.k, method=method, convention=convention,
                            radius=field.radius[i] + 0.3, cylinder=field.cylinder[i])
            for i in range(2)  # the valid ones
        ]
        attraction = gains.k_att * (goal - p)
        np.testing.assert_allclose(force, attraction + sum(per_obstacle), rtol=1e-12, atol=1e-12)
        assert np.linalg.norm(per_obstacle[1]) > 0.1  # the near cylinder pushes, so the test could fail


def test_component_first_obstacles_equal_one_at_a_time():
    """(3, M) obstacle arrays give the M single-obstacle potentials and weights."""
    rng = np.random.default_rng(7)
    p, v = jnp.asarray(rng.normal(size=3)), jnp.asarray(rng.normal(size=3))
    p_o, v_o = jnp.asarray(rng.normal(size=(5, 3)) * 2), jnp.asarray(rng.normal(size=(5, 3)))
    radius, cylinder = jnp.asarray(rng.uniform(0.1, 0.5, 5)), jnp.array([True, False, True, False, False])
    kw = dict(GAINS, method="direction_velocity", convention="intent")
    together = weighted_repulsive_potential(p, v, p_o.T, v_o.T, radius=radius, cylinder=cylinder, **kw)
    one = [weighted_repulsive_potential(p, v, p_o[i], v_o[i], radius=radius[i], cylinder=cylinder[i], **kw)
           for i in range(5)]
    np.testing.assert_allclose(together, one, rtol=1e-6)
    w = weight(p, v, p_o.T, v_o.T, gamma=1.5, k=0.7, method="direction_velocity", convention="literal",
               cylinder=cylinder)
    assert w.shape == (5,)
    np.testing.assert_allclose(w, [weight(p, v, p_o[i], v_o[i], gamma=1.5, k=0.7, method="direction_velocity",
                                          convention="literal", cylinder=cylinder[i]) for i in range(5)], rtol=1e-6)


@settings(max_examples=30, deadline=None)
@given(gamma=st.floats(0.0, 5.0), k=st.floats(0.0, 3.0))
def test_every_normalised_weight_is_one_at_its_reference_condition(gamma, k):
    """ω / ω(θ = 90°, c = 0) = 1 there, for the weight of every registered potential-field planner and any
    gains (SPEC 3, fair strength)."""
    from jaxapf.planners.weights import Normalised, reference_sight

    gains = Gains.unchecked({**Gains().as_arrays(jnp.float32), "gamma": jnp.float32(gamma), "k": jnp.float32(k)})
    weights = {name: p.weight for name, p in PLANNERS.items() if isinstance(p, APF)}
    assert {"basic", "direction", "direction_velocity", "ge_cui_bounded"} <= set(weights)
    for name, w in weights.items():
        value = Normalised(w)(reference_sight(jnp.float32), gains, convention="intent", eps_v=1e-3)
        np.testing.assert_allclose(float(value), 1.0, rtol=1e-6, err_msg=name)


def test_normalised_weights_are_the_paper_weights_over_their_abeam_values():
    rng = np.random.default_rng(3)
    g = dict(gamma=1.7, k=0.6)
    for _ in range(5):
        p, v, p_o, v_o = (jnp.asarray(rng.normal(size=3)) for _ in range(4))
        w_d = weight(p, v, p_o, v_o, method="direction", convention="intent", **g)
        w_dv = weight(p, v, p_o, v_o, method="direction_velocity", convention="literal", **g)
        np.testing.assert_allclose(weight(p, v, p_o, v_o, method="direction_normalised", convention="intent", **g),
                                   w_d / (1 + g["gamma"] / 2), rtol=1e-6)
        np.testing.assert_allclose(weight(p, v, p_o, v_o, method="direction_velocity_normalised",
                                          convention="literal", **g), w_dv / ((1 + g["gamma"] / 2) * 2), rtol=1e-6)
    # hovering beside a static obstacle every normalised weight is basic's 1; with γ = 0 the
    # normalised direction planner's force is basic's
    p, p_o = jnp.array([0.0, 0.0, 0.0]), jnp.array([1.5, 0.0, 0.0])
    for name in ("direction_normalised", "direction_velocity_normalised"):
        assert float(weight(p, jnp.zeros(3), p_o, jnp.zeros(3), method=name, convention="intent", **g)) == 1.0
    kw = dict(k_rep=3.0, d_s=4.0, gamma=0.0, k=0.0, convention="intent")
    v = jnp.array([0.5, 0.3, 0.0])
    np.testing.assert_allclose(repulsive_force(p, v, p_o, jnp.zeros(3), method="direction_normalised", **kw),
                               repulsive_force(p, v, p_o, jnp.zeros(3), method="basic", **kw), rtol=1e-6)


#: The members of the fused program the accelerator policy flies the paper's methods in (and a normalised one).
FUSED = ("basic", "direction", "direction_velocity", "direction_velocity_normalised")


@pytest.mark.parametrize("convention", CONVENTIONS)
@pytest.mark.parametrize("choice", range(len(FUSED)))
def test_a_fused_weight_is_the_chosen_methods_own_in_value_and_force(choice, convention):
    """``Chosen`` at choice i: the weight, the potential and the force (its gradient) of method i, to float64
    rounding, on a field with a cylinder, a moving sphere and a padded slot; a weight chosen wrongly differs by
    far more (γ = 1.5, k = 0.7 and a closing obstacle make every member's ω different)."""
    from jaxapf.planners.apf import fused

    planner = fused("+".join(FUSED))
    own = PLANNERS.get(FUSED[choice]).weight
    gains = Gains(k_rep=3.0, d_s=4.0, gamma=1.5, k=0.7)
    chosen = Gains.unchecked({**gains, "weight_choice": float(choice)})
    kw = dict(convention=convention, r_uav=0.3)
    with jax.enable_x64(True):
        field = jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float64) if a.dtype.kind == "f" else a,
                                       _field(True))
        p, v, goal = jnp.array([0.2, -0.4, 0.3]), jnp.array([1.0, 0.2, -0.1]), jnp.array([10.0, 0.0, 0.0])
        forces = {m: total_force(p, v, 0.5, goal, field, gains, method=PLANNERS.get(m).weight, **kw) for m in FUSED}
        force = total_force(p, v, 0.5, goal, field, chosen, method=planner.weight, **kw)
        np.testing.assert_allclose(force, forces[FUSED[choice]], rtol=1e-12, atol=1e-12)
        assert all(np.abs(forces[m] - force).max() > 1e-3 for m in FUSED if m != FUSED[choice])
        u = total_potential(p, v, 0.5, goal, field, chosen, method=planner.weight, **kw)
        np.testing.assert_allclose(u, total_potential(p, v, 0.5, goal, field, gains, method=own, **kw), rtol=1e-12)
        lo, hi = planner.weight.bounds(chosen)
        np.testing.assert_allclose([lo, hi], own.bounds(gains), rtol=1e-12)


def test_only_potential_field_planners_without_extra_forces_fuse():
    from jaxapf.planners.apf import fusable, fused

    assert fusable(PLANNERS.get("basic")) and fusable(PLANNERS.get("direction_velocity_normalised"))
    assert not fusable(PLANNERS.get("vortex")) and not fusable(PLANNERS.get("mppi"))
    assert set(fused("basic+direction").gains) >= {*PLANNERS.get("direction").gains}
    assert "weight_choice" in {g.name for g in fused("basic+direction").gains}
    with pytest.raises(ConfigError, match=r"method = 'basic\+vortex'.*not vortex"):
        fused("basic+vortex")
    with pytest.raises(ConfigError, match="is not a registered planner"):
        fused("basic+magic")

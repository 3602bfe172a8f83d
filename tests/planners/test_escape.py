"""The stall-escape planner (jaxapf.planners.escape): detection, virtual goals, the random first side,
alternation, closed loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario, outcomes

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Obstacles, Scenario
from jaxapf.engine import rollout
from jaxapf.gains import Gains
from jaxapf.planners import PLANNERS

PLANNER = PLANNERS.get("basic_escape")
SIM = SimConfig.from_flat(method="basic_escape")  # dt 0.1 s, v_stall 0.1 m/s, r_goal 0.5 m
GAINS = Gains(t_detect=0.25, t_escape=0.35, d_escape=3.0)
GOAL = jnp.asarray([10.0, 0.0, 2.0])
NO_OBSTACLES = Obstacles(position=jnp.zeros((1, 3)), velocity=jnp.zeros((1, 3)), radius=jnp.zeros(1),
                         cylinder=jnp.zeros(1, bool), valid=jnp.zeros(1, bool)).columns()
_step = jax.jit(lambda state, x, goal: PLANNER.reference(state, x, 0.0, goal, NO_OBSTACLES, GAINS, SIM, 4))


def _key(seed):
    return jax.random.key_data(jax.random.fold_in(jax.random.key(3), seed))


def _run(x, goal, steps, key=None):
    state = PLANNER.init(Scenario(start=x[:3], goal=goal, obstacles=NO_OBSTACLES, key=key), GAINS, SIM, 4)
    states = []
    for _ in range(steps):
        _, state = _step(state, x, goal)
        states.append(state)
    return states


def test_a_hovering_uav_far_from_the_goal_escapes_to_a_random_side_then_the_other():
    x = jnp.asarray([0.0, 0.0, 2.0, 0.0, 0.0, 0.0])
    firsts = []
    for seed in range(8):
        states = _run(x, GOAL, 12, _key(seed))
        escapes = [int(s.escapes) for s in states]
        # slow for 0.1, 0.2, 0.3 >= 0.25 s: the third step starts an escape of 0.35 s (steps 3-6, left
        # 0.35, 0.25, 0.15, 0.05), then detection starts afresh: 0.1, 0.2, 0.3 -> the second escape
        assert escapes == [0, 0, 1, 1, 1, 1, 1, 1, 1, 2, 2, 2]
        side = float(states[2].virtual_goal[1]) / 3.0  # +1: left of +x, -1: right
        assert abs(side) == 1.0 and float(states[0].first_side) == side
        np.testing.assert_allclose(states[2].virtual_goal, [0.0, 3.0 * side, 2.0], atol=1e-6)
        np.testing.assert_allclose(states[9].virtual_goal, [0.0, -3.0 * side, 2.0], atol=1e-6)  # then the other
        assert [round(float(s.left), 2) for s in states[2:7]] == [0.35, 0.25, 0.15, 0.05, 0.0]
        firsts.append(side)
    assert set(firsts) == {1.0, -1.0}


def test_the_first_side_is_a_fair_coin_of_the_field_key():
    sides = np.asarray([float(PLANNER.init(Scenario(start=GOAL, goal=GOAL, obstacles=NO_OBSTACLES, key=_key(i)),
                                           GAINS, SIM, 4).first_side) for i in range(400)])
    assert abs(np.mean(sides == 1.0) - 0.5) < 0.08  # 4 standard deviations of 400 fair coins


def test_the_escape_hands_the_virtual_goal_to_the_wrapped_planner():
    x = jnp.asarray([0.0, 0.0, 2.0, 0.0, 0.0, 0.0])
    state = _run(x, GOAL, 3)[-1]  # escaping now
    ref, _ = _step(state, x, GOAL)
    inner, _ = PLANNER.inner.reference((), x, 0.0, state.virtual_goal, NO_OBSTACLES, GAINS, SIM, 4)
    np.testing.assert_array_equal(np.asarray(ref), np.asarray(inner))
    assert float(ref[-1, 1]) * float(state.first_side) > 0.0  # the reference now heads to that side, not along +x


def test_no_escape_near_the_goal_or_while_moving():
    near = jnp.asarray([9.7, 0.0, 2.0, 0.0, 0.0, 0.0])  # 0.3 m from the goal (< r_goal)
    assert all(int(s.escapes) == 0 for s in _run(near, GOAL, 20))
    moving = jnp.asarray([0.0, 0.0, 2.0, 0.2, 0.0, 0.0])  # 0.2 m/s > v_stall
    assert all(int(s.escapes) == 0 for s in _run(moving, GOAL, 20))


@pytest.mark.slow
def test_same_field_same_episode_and_gradients_flow():
    """Deterministic per field key, jit/vmap-compatible, and differentiable in d_escape."""
    scenario = one_obstacle_scenario(16.0, 8.0, 1.5)
    sim, mpc = SimConfig.from_flat(method="basic_escape", t_max=12.0), MPCConfig(horizon=6, iters=10)
    run = jax.jit(rollout, static_argnums=(2, 3))
    a, b = run(scenario, Gains(), sim, mpc), run(scenario, Gains(), sim, mpc)
    np.testing.assert_array_equal(np.asarray(a.position), np.asarray(b.position))

    def final_y(d):
        return rollout(scenario, Gains().replace(d_escape=d), sim, mpc).position[-1, 1]

    grad = jax.grad(final_y)(4.0)
    assert np.isfinite(float(grad)) and float(grad) != 0.0


@pytest.mark.slow
def test_the_escape_passes_an_obstacle_on_the_line_to_the_goal():
    outcome = outcomes(one_obstacle_scenario(16.0, 8.0, 1.5), ("basic", "basic_escape"))
    assert outcome["basic"] == {"success": False, "collision": False, "stalled": True}
    assert outcome["basic_escape"] == {"success": True, "collision": False, "stalled": False}


def test_registered_with_its_gains():
    assert [g.name for g in PLANNER.gains] == ["k_rep", "d_s", "k_att", "eta", "t_detect", "t_escape", "d_escape"]

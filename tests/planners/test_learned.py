"""The learned weight ω_θ and the ``learned_weight`` planner (jaxapf.planners.learned)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import three_obstacle_field
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.engine import evaluate, rollout
from jaxapf.gains import Gains
from jaxapf.planners import PLANNERS
from jaxapf.planners.learned import FEATURES, SIZE, WIDTH, LearnedWeight, initial_params
from jaxapf.planners.potentials import weight
from jaxapf.validation import ConfigError

MPC = MPCConfig(horizon=10, iters=20)


def _random_params(seed: int, scale: float = 0.5) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, scale, SIZE)


def _numpy_omega(theta, p, v, p_o, v_o, d_s, eps_v=1e-3):
    """Independent: the features and the 3-W-W-1 network written out in numpy (one spherical obstacle)."""
    n = len(FEATURES)
    w1 = theta[:n * WIDTH].reshape(WIDTH, n)
    at = n * WIDTH
    b1, at = theta[at:at + WIDTH], at + WIDTH
    w2, at = theta[at:at + WIDTH * WIDTH].reshape(WIDTH, WIDTH), at + WIDTH * WIDTH
    b2, at = theta[at:at + WIDTH], at + WIDTH
    w3, b3 = theta[at:at + WIDTH], theta[at + WIDTH]
    s = p_o - p
    dist = np.linalg.norm(s)
    cos = v @ s / (dist * np.sqrt(v @ v + eps_v**2))
    x = np.array([cos, np.tanh((v - v_o) @ s / dist), min(dist / d_s, 1.0)])
    z = w3 @ np.tanh(w2 @ np.tanh(w1 @ x + b1) + b2) + b3
    return np.log1p(np.exp(z))


def _omega(theta, p, v, p_o, v_o, d_s=4.0, method=None):
    method = method or LearnedWeight()
    return weight(jnp.asarray(p), jnp.asarray(v), jnp.asarray(p_o), jnp.asarray(v_o), method=method,
                  convention="intent", omega_params=jnp.asarray(theta), d_s=d_s)


def test_the_network_matches_an_independent_numpy_one():
    rng = np.random.default_rng(3)
    with jax.enable_x64(True):
        for trial in range(20):
            theta = _random_params(trial)
            p, v, p_o, v_o = (rng.normal(size=3) for _ in range(4))
            got = float(_omega(theta, p, v, p_o, v_o))
            np.testing.assert_allclose(got, _numpy_omega(theta, p, v, p_o, v_o, 4.0), rtol=1e-12)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**16), scale=st.floats(0.01, 20.0), geometry=st.lists(st.floats(-50, 50), min_size=12,
                                                                                   max_size=12))
def test_the_weight_is_positive_for_any_parameters_and_geometry(seed, scale, geometry):
    p, v, p_o, v_o = np.asarray(geometry, np.float32).reshape(4, 3)
    omega = float(_omega(_random_params(seed, scale).astype(np.float32), p, v, p_o, v_o))
    assert np.isfinite(omega) and omega >= 0.0  # softplus: > 0 in exact arithmetic, may round to 0 in float32
    with jax.enable_x64(True):
        assert float(_omega(_random_params(seed, min(scale, 2.0)), p, v, p_o, v_o)) > 0.0


@pytest.mark.slow  # closed loops compiled and flown
def test_the_default_parameters_are_the_classical_potential():
    """θ's default gives ω ≡ 1 wherever the obstacle is, so the planner flies ``basic``'s episodes up to rounding."""
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        default = np.asarray(initial_params())
        for _ in range(10):
            assert abs(float(_omega(default, *(rng.normal(size=3) * 5 for _ in range(4)))) - 1.0) < 1e-15
        field = three_obstacle_field(dtype=jnp.float64)
        tracks = {m: rollout(field, Gains(), SimConfig.from_flat(method=m, t_max=20.0), MPC).position
                  for m in ("basic", "learned_weight")}
        np.testing.assert_allclose(tracks["learned_weight"], tracks["basic"], atol=1e-9)


def test_an_input_left_out_does_not_move_the_weight():
    theta = _random_params(7)
    p, v, p_o = np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([3.0, 0.5, 0.0])
    only_direction = LearnedWeight(inputs=("direction",))
    still, coming = np.zeros(3), np.array([-1.5, 0.0, 0.0])  # the same direction cosine, other closing speeds
    with jax.enable_x64(True):
        assert float(_omega(theta, p, v, p_o, still, method=only_direction)) == float(
            _omega(theta, p, v, p_o, coming, method=only_direction))
        assert float(_omega(theta, p, v, p_o, still)) != pytest.approx(float(_omega(theta, p, v, p_o, coming)),
                                                                       rel=1e-6)
    with pytest.raises(ConfigError, match="LearnedWeight.inputs"):
        LearnedWeight(inputs=("speed",))


@pytest.mark.slow  # closed loops compiled and flown
def test_closed_loop_gradient_in_the_parameters_matches_central_differences():
    """d/dθ of a smooth closed-loop quantity (the mean distance to the goal over a 4 s episode, float64)
    against central differences on coordinates of every layer."""
    sim = SimConfig.from_flat(method="learned_weight", t_max=4.0)
    with jax.enable_x64(True):
        field = three_obstacle_field(dtype=jnp.float64)
        theta0 = jnp.asarray(_random_params(11, 0.3))

        def loss(theta):
            traj = rollout(field, Gains.unchecked(dict(Gains()) | {"omega_params": theta}), sim, MPC)
            return jnp.mean(jnp.linalg.norm(traj.position - field.goal, axis=-1))

        grad = np.asarray(jax.jit(jax.grad(loss))(theta0))
        value = jax.jit(loss)
        n = len(FEATURES)
        coordinates = (0, n * WIDTH - 1, n * WIDTH + 3, n * WIDTH + WIDTH + 17, SIZE - WIDTH - 2, SIZE - 1)
        for i in coordinates:
            h = 1e-5
            e = jnp.zeros(SIZE).at[i].set(h)
            fd = (float(value(theta0 + e)) - float(value(theta0 - e))) / (2 * h)
            assert grad[i] == pytest.approx(fd, rel=1e-4, abs=1e-9), i
        assert np.count_nonzero(grad) > SIZE // 2


@pytest.mark.slow  # a closed loop compiled per component
@pytest.mark.parametrize("flat", [dict(filter="cbf"), dict(sensor="noisy", disturbance="wind"),
                                  dict(plant="quadrotor"), dict(estimator="integral")])
def test_it_composes_with_the_loop_components(flat):
    """A batch of two networks per component: finite metrics, and two parameter vectors fly different episodes."""
    sim = SimConfig.from_flat(method="learned_weight", t_max=10.0, **flat)
    field = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), three_obstacle_field(dtype=jnp.float32))
    gains = Gains(omega_params=np.stack([initial_params(), initial_params()]) + np.stack([np.zeros(SIZE),
                                                                                           _random_params(2)]))
    out = evaluate(field, gains, sim, MPC, metrics=("success", "collision", "min_clearance"))
    assert out["min_clearance"].shape == (2, 2) and np.all(np.isfinite(out["min_clearance"]))
    assert out["min_clearance"][0, 0] != out["min_clearance"][1, 0]


def test_it_is_registered_with_its_gains():
    assert [g.name for g in PLANNERS.get("learned_weight").gains][:2] == ["omega_params", "d_s"]
    with pytest.raises(ConfigError, match="omega_params .* is not a grid axis"):
        Gains.grid(omega_params=[0.0, 1.0])
    with pytest.raises(ConfigError, match="omega_params has shape"):
        Gains(omega_params=[1.0, 2.0])


@pytest.mark.slow  # closed loops compiled and flown
def test_a_swarm_of_learned_weights_flies_two_uavs_past_each_other():
    """Two UAVs swapping places, each seeing the other as an obstacle through ω_θ (a trained-looking network:
    random parameters): finite tracks, both UAVs move, and they keep apart."""
    from jaxapf.datatypes import Obstacles
    from jaxapf.datatypes.swarm import Swarm
    from jaxapf.engine.swarm import swarm_rollout

    swarm = Swarm(start=jnp.asarray([[0.0, 0.0, 2.0], [10.0, 0.3, 2.0]]), goal=jnp.asarray([[10.0, 0.0, 2.0],
                                                                                      [0.0, 0.3, 2.0]]),
                  valid=jnp.asarray([True, True]), obstacles=Obstacles.empty(2, jnp.float32))
    sim = SimConfig.from_flat(method="learned_weight", t_max=20.0)
    gains = Gains(omega_params=np.asarray(initial_params()) + _random_params(5, 0.2))
    p = np.asarray(jax.jit(lambda s: swarm_rollout(s, gains, sim, MPC).position)(swarm))
    assert np.all(np.isfinite(p)) and np.linalg.norm(p[0, -1] - p[0, 0]) > 3.0
    assert np.min(np.linalg.norm(p[0] - p[1], axis=-1)) > 2 * sim.vehicle.r_uav


def test_the_ablation_spec_trains_variants_that_each_leave_out_one_input(repo_root):
    """sweeps/learned-weight-ablation.toml: its plugin registers one variant per input, each feeding that input
    as 0, every arm selected by gradient under the same budget."""
    from jaxapf.compare import load_compare_spec

    spec, _ = load_compare_spec(repo_root / "sweeps" / "learned-weight-ablation.toml")
    assert spec.baseline == "learned_weight" and {spec.selection.search_of(m) for m in spec.methods} == {"gradient"}
    for dropped in FEATURES:
        weight = PLANNERS.get(f"learned_weight_without_{dropped}").weight
        assert f"learned_weight_without_{dropped}" in spec.methods
        assert set(weight.inputs) == set(FEATURES) - {dropped}

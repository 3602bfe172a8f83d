"""The noisy sensor (noise, latency, range, dropout, own state) and the wind (constant + OU gusts)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import three_obstacle_field

from jaxapf import Gains, family_params, make_scenarios
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Scenario
from jaxapf.engine import evaluate
from jaxapf.world import DISTURBANCES
from jaxapf.world.sensing import SENSORS

NOISY = SENSORS.get("noisy")
WIND = DISTURBANCES.get("wind")
DT = 0.1


def field(seed: int = 0) -> Scenario:
    """The conftest field (a moving sphere among them) with the key of field ``seed``."""
    base = three_obstacle_field(dtype=jnp.float32)
    return Scenario(base.start, base.goal, base.obstacles,
                    key=jax.random.key_data(jax.random.fold_in(jax.random.key(7), seed)))


def observe(scenario, gains, sim, steps, path=None):
    """Run the sensor alone for ``steps`` steps along ``path`` (steps, 6; default: the UAV at rest at
    the start): the estimates, observed obstacles and diagnostics of every step."""
    gains = gains.as_arrays(jnp.float32)
    obstacles = scenario.obstacles.columns()
    if path is None:
        path = jnp.broadcast_to(jnp.concatenate([scenario.start, jnp.zeros(3)]), (steps, 6))

    def step(state, inputs):
        k, x = inputs
        est, seen, state, diag = NOISY(state, x, k, scenario, obstacles, gains, sim)
        return state, (est, seen, diag)
    return jax.lax.scan(step, NOISY.init(scenario, gains, sim), (jnp.arange(steps), path))[1]


def centres(observed, k):
    """Where the stack puts the observed obstacles at step k (3, M)."""
    return observed.position[k] + observed.velocity[k] * (k * DT)


def truth(scenario, t):
    return (scenario.obstacles.position + scenario.obstacles.velocity * t).T


def test_at_zero_levels_the_noisy_sensor_passes_the_truth_on_bit_for_bit():
    sc = field()
    sim = SimConfig.from_flat(sensor="noisy")
    est, seen, diag = observe(sc, Gains(), sim, 40)
    obstacles = sc.obstacles.columns()
    np.testing.assert_array_equal(seen.position, np.broadcast_to(obstacles.position, seen.position.shape))
    np.testing.assert_array_equal(seen.velocity, np.broadcast_to(obstacles.velocity, seen.velocity.shape))
    np.testing.assert_array_equal(seen.valid, np.broadcast_to(obstacles.valid, seen.valid.shape))
    np.testing.assert_array_equal(est[:, :3], np.broadcast_to(sc.start, (40, 3)))


@pytest.mark.slow
@pytest.mark.parametrize("steps_late", [0, 1, 3, 7])
def test_latency_delays_observations_by_exactly_d_steps(steps_late):
    sc = field()
    sim = SimConfig.from_flat(sensor="noisy", max_latency=5)
    _, seen, _ = observe(sc, Gains(latency=steps_late * DT), sim, 20)
    d = min(steps_late, 5)  # clipped to max_latency
    valid = np.asarray(sc.obstacles.valid)
    for k in range(20):
        np.testing.assert_allclose(np.asarray(centres(seen, k))[:, valid], truth(sc, (k - d) * DT)[:, valid],
                                   atol=2e-5)


@pytest.mark.slow
def test_position_and_velocity_noise_have_their_laws_and_are_independent_of_the_planners_gains():
    sigma_p, sigma_v = 0.4, 0.2
    sim = SimConfig.from_flat(sensor="noisy")
    gains = Gains(sigma_obs_p=sigma_p, sigma_obs_v=sigma_v)
    fields = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *[field(seed) for seed in range(40)])
    run = jax.jit(jax.vmap(lambda sc, g: observe(sc, g, sim, 25)[1], in_axes=(0, None)))
    seen = run(fields, gains)
    other = run(fields, gains.replace(k_rep=3.0, gamma=7.0))
    np.testing.assert_array_equal(seen.position, other.position)
    valid = np.asarray(fields.obstacles.valid[0])
    t = DT * np.arange(25)[None, :, None, None]
    where = np.asarray(seen.position) + np.asarray(seen.velocity) * t  # (fields, steps, 3, M)
    columns = fields.obstacles.columns()
    true = np.asarray(columns.position)[:, None] + np.asarray(columns.velocity)[:, None] * t
    errors_p = (where - true)[..., valid].ravel()
    errors_v = (np.asarray(seen.velocity) - np.asarray(columns.velocity)[:, None])[..., valid].ravel()
    n = errors_p.size  # 40 fields x 25 steps x 3 axes x 3 obstacles
    assert abs(errors_p.mean()) < 4 * sigma_p / np.sqrt(n) and abs(errors_p.std() / sigma_p - 1) < 0.05
    assert abs(errors_v.mean()) < 4 * sigma_v / np.sqrt(n) and abs(errors_v.std() / sigma_v - 1) < 0.05


@pytest.mark.slow
@pytest.mark.parametrize("latency", [0.0, 0.3])
def test_a_differenced_velocity_is_the_finite_difference_of_consecutive_noisy_positions(latency):
    sc = field()
    sigma = 0.05
    sim = SimConfig.from_flat(sensor="noisy", velocity_estimate="differenced")
    _, seen, _ = observe(sc, Gains(sigma_obs_p=sigma, latency=latency), sim, 30)
    valid = np.asarray(sc.obstacles.valid)
    z = np.stack([np.asarray(centres(seen, k)) for k in range(30)])
    difference = (z[1:] - z[:-1]) / DT
    np.testing.assert_allclose(np.asarray(seen.velocity)[1:][..., valid], difference[..., valid], atol=2e-3)
    spread = (np.asarray(seen.velocity) - np.asarray(sc.obstacles.columns().velocity))[..., valid].std()
    assert abs(spread / (np.sqrt(2) * sigma / DT) - 1) < 0.25


def test_an_obstacle_beyond_range_is_unknown_until_it_comes_within_range_then_is_tracked():
    sc = field()
    sim = SimConfig.from_flat(sensor="noisy")
    # the UAV flies along x at 1 m/s; the static sphere at x = 4 (radius 1) comes within 2 m at t = 0.7 s
    t = DT * np.arange(30)
    path = jnp.asarray(np.stack([t, 0 * t, 0 * t, 1 + 0 * t, 0 * t, 0 * t], axis=1), jnp.float32)
    _, seen, diag = observe(sc, Gains(sense_range=2.0), sim, 30, path)
    first = int(np.argmax(np.asarray(seen.valid)[:, 0]))
    clearance = np.linalg.norm(np.asarray([4.0, 0.3, 0.0]) - np.asarray(path[:, :3]), axis=1) - 1.0 - 0.3
    assert first == int(np.argmax(clearance <= 2.0))
    assert not np.asarray(seen.valid)[:first, 0].any() and np.asarray(seen.valid)[first:, 0].all()
    # unseen within d_sense = 4 m: the static sphere before it is detected
    assert int(np.asarray(diag["unseen_near"])[:first].min()) >= 1


@pytest.mark.slow
def test_dropout_loses_the_stated_share_of_measurements_and_tracks_coast():
    sc = field()
    sim = SimConfig.from_flat(sensor="noisy")
    _, never, _ = observe(sc, Gains(dropout=1.0), sim, 10)
    assert not np.asarray(never.valid).any()
    _, seen, _ = observe(sc, Gains(dropout=0.3, sigma_obs_p=0.2), sim, 400)
    position = np.asarray(seen.position)[..., :3]
    fresh = np.any(position[1:] != position[:-1], axis=1)  # a new noisy measurement replaced the track
    assert abs(fresh.mean() - 0.7) < 0.04
    held = ~fresh
    np.testing.assert_array_equal(position[1:][:, :, :][np.broadcast_to(held[:, None], position[1:].shape)],
                                  position[:-1][np.broadcast_to(held[:, None], position[1:].shape)])


def test_the_own_state_estimate_has_the_stated_noise():
    sc = field()
    sim = SimConfig.from_flat(sensor="noisy")
    est, _, _ = observe(sc, Gains(sigma_self_p=0.3, sigma_self_v=0.1), sim, 2000)
    error = np.asarray(est) - np.concatenate([np.asarray(sc.start), np.zeros(3)])
    np.testing.assert_allclose(error[:, :3].std(axis=0), 0.3, rtol=0.06)
    np.testing.assert_allclose(error[:, 3:].std(axis=0), 0.1, rtol=0.06)
    assert np.all(np.abs(error.mean(axis=0)) < 4 * np.array([0.3] * 3 + [0.1] * 3) / np.sqrt(2000))


@pytest.mark.slow
def test_ou_gusts_have_zero_mean_their_variance_and_exponential_correlation():
    sigma, tau, steps = 1.5, 0.8, 400
    sim = SimConfig.from_flat(disturbance="wind")
    gains = Gains(gust_sigma=sigma, gust_tau=tau, wind_drag=1.0).as_arrays(jnp.float32)

    def gusts(seed):
        sc = field(seed)

        def step(state, k):
            push, state = WIND(state, k, sc, gains, sim)
            return state, push
        return jax.lax.scan(step, WIND.init(sc, gains, sim), jnp.arange(steps))[1]
    g = np.asarray(jax.vmap(gusts)(jnp.arange(300)))  # (fields, steps, 3)
    assert abs(g.mean()) < 4 * sigma * np.sqrt(2 * tau / (DT * g.size))  # correlated samples: fewer effective
    np.testing.assert_allclose(g.var(), sigma**2, rtol=0.05)
    for lag in (1, 4, 8):
        corr = np.mean(g[:, lag:] * g[:, :-lag]) / g.var()
        np.testing.assert_allclose(corr, np.exp(-lag * DT / tau), atol=0.03)
    # every step, not only in the long run: the law is stationary from g_0 on
    np.testing.assert_allclose(g[:, 0].var(), sigma**2, rtol=0.15)


def test_gust_vertical_scales_only_the_vertical_gusts_and_its_default_is_the_isotropic_world():
    """``gust_vertical`` = r multiplies the z gusts by r and leaves x and y bit for bit; at its
    default 1 every push equals the former isotropic law (one σ on every axis), to rounding."""
    sim = SimConfig.from_flat(disturbance="wind")
    sc, steps = field(3), 50

    def pushes(gains):
        gains = gains.as_arrays(jnp.float32)

        def step(state, k):
            push, state = WIND(state, k, sc, gains, sim)
            return state, push
        return np.asarray(jax.lax.scan(step, WIND.init(sc, gains, sim), jnp.arange(steps))[1])

    base = dict(wind_speed=3.0, wind_heading=30.0, gust_sigma=1.2, gust_tau=0.7, wind_drag=0.4)
    iso, low, none = (pushes(Gains(**base, gust_vertical=r)) for r in (1.0, 0.25, 0.0))
    np.testing.assert_array_equal(low[:, :2], iso[:, :2])
    np.testing.assert_array_equal(none[:, :2], iso[:, :2])
    np.testing.assert_allclose(low[:, 2], 0.25 * iso[:, 2], rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(none[:, 2], 0.0)  # no vertical mean wind, no vertical gusts
    assert np.std(iso[:, 2]) > 0.1

    # the former law, one σ on every axis, written out and flown the same way
    g = Gains(**base).as_arrays(jnp.float32)

    def former(gust, k):
        heading = jnp.deg2rad(g.wind_heading)
        mean = g.wind_speed * jnp.stack([jnp.cos(heading), jnp.sin(heading), jnp.zeros_like(heading)])
        decay = jnp.exp(-sim.episode.dt / g.gust_tau)
        push = (g.wind_drag * (mean + gust)).astype(sc.start.dtype)
        return decay * gust + g.gust_sigma * jnp.sqrt(1.0 - decay * decay) * WIND._draw(sc, k), push
    expected = np.asarray(jax.lax.scan(former, g.gust_sigma * WIND._draw(sc, -1), jnp.arange(steps))[1])
    np.testing.assert_allclose(pushes(Gains(**base)), expected, rtol=1e-6, atol=1e-7)
    assert Gains().gust_vertical == 1.0


@pytest.mark.slow
def test_a_constant_wind_pushes_the_double_integrator_by_drag_times_speed():
    sc = jax.tree_util.tree_map(lambda x: x[None], field())
    sim = SimConfig.from_flat(method="basic", disturbance="wind", t_max=5.0)
    gains = jax.tree_util.tree_map(lambda x: np.asarray([x]), Gains(wind_speed=4.0, wind_heading=90.0,
                                                                    wind_drag=0.25))
    m = evaluate(sc, gains, sim, MPCConfig(horizon=8, iters=15))
    np.testing.assert_allclose(float(m["accel_error_rms"][0, 0]), 1.0, rtol=1e-4)


@pytest.mark.slow
def test_a_grid_over_noise_levels_is_one_program_and_zero_noise_matches_the_ideal_sensor():
    scenarios = make_scenarios(1, family_params("dynamic"), 16)
    mpc = MPCConfig(horizon=8, iters=15)
    sim = SimConfig.from_flat(method="basic", t_max=20.0)
    grid = jax.tree_util.tree_map(lambda *x: np.asarray(x, np.float32),
                                  *[Gains(sigma_obs_p=s, latency=s) for s in (0.0, 0.2, 0.5)])
    noisy = evaluate(scenarios, grid, sim.replace(sensor="noisy"), mpc)
    ideal = evaluate(scenarios, jax.tree_util.tree_map(lambda x: np.asarray([x]), Gains()), sim, mpc)
    for name in ("success", "collision", "min_clearance", "steps"):
        np.testing.assert_array_equal(noisy[name][0], ideal[name][0])
    assert not np.array_equal(noisy["min_clearance"][2], ideal["min_clearance"][0])

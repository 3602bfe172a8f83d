"""The quadrotor plant (paper eq. 1–3): hover, frames, the linearised response, the limit of a stiff
attitude loop, rotor saturation, orthonormality and gradients."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario
from scipy.integrate import solve_ivp

from jaxapf import Gains, rollout
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.world import HUMMINGBIRD, PLANTS, Quadrotor
from jaxapf.world.quadrotor import rotation

QUAD = PLANTS.get("quadrotor")
SIM = SimConfig.from_flat(plant="quadrotor", substeps=20)
G = HUMMINGBIRD.gravity


def fly(accels, gains=None, sim=SIM, start=(0.0, 0.0, 2.0), dtype=jnp.float32, plant=QUAD):
    """Plant states and diagnostics under a sequence of world-frame commands (steps, 3)."""
    gains = (gains or Gains()).as_arrays(dtype)
    state = plant.init(jnp.asarray(start, dtype), gains, sim)

    def step(s, a):
        s, diag = plant.step(s, a, jnp.zeros(3, dtype), gains, sim)
        return s, (plant.kinematics(s), s, diag)
    return jax.lax.scan(step, state, jnp.asarray(accels, dtype))


def test_it_hovers_at_the_weight_shared_by_four_rotors():
    final, (x, states, diag) = fly(np.zeros((100, 3)))
    np.testing.assert_allclose(final.rotors, HUMMINGBIRD.mass * G / 4, rtol=1e-6)
    np.testing.assert_allclose(x[:, :3], np.broadcast_to([0.0, 0.0, 2.0], (100, 3)), atol=1e-5)
    assert float(jnp.max(diag["tilt"])) < 1e-5 and float(jnp.sum(diag["saturated_time"])) == 0.0


@pytest.mark.slow
def test_a_command_along_each_world_axis_moves_the_vehicle_that_way():
    """Frames: jaxapf's z-up world, the paper's z-down frame inside. x and y respond alike (J_xx = J_yy)."""
    a = 0.5
    for axis in range(3):
        command = np.zeros((30, 3))
        command[:, axis] = a
        _, (x, _, _) = fly(command)
        moved = np.asarray(x[-1, :3]) - np.array([0.0, 0.0, 2.0])
        assert moved[axis] > 0.5 * 0.5 * a * 3.0**2 * 0.8, (axis, moved)
        assert np.all(np.abs(np.delete(moved, axis)) < 0.02 * moved[axis]), (axis, moved)
    _, (xx, _, _) = fly(np.tile([a, 0.0, 0.0], (30, 1)))
    _, (xy, _, _) = fly(np.tile([0.0, a, 0.0], (30, 1)))
    np.testing.assert_allclose(xx[:, 0], xy[:, 1], atol=1e-4)


@pytest.mark.parametrize("substeps", [5, 20, 50])
def test_the_rotor_lag_is_the_exact_first_order_response_to_a_step(substeps):
    """A vertical step command from hover (level, so all four rotors alike): the total thrust is
    ``m(g + a) - m a e^{-t/τ}``. The mean thrust over every control step (from the velocity) matches
    it to 1e-5 relative, position and velocity match its integrals, and the time constant measured
    from the simulated step, ``∫(F_c - F) dt / (F_c - F_0)``, is the stated ``motor_tau``, whatever
    the number of sub-steps. (The end-of-sub-step force over the whole sub-step gave about τ - h/2.)"""
    a, tau, steps, dt = 3.0, 0.0125, 10, 0.1
    sim = SimConfig.from_flat(plant="quadrotor", substeps=substeps)
    m = HUMMINGBIRD.mass
    with jax.enable_x64(True):
        _, (x, states, _) = fly(np.tile([0.0, 0.0, a], (steps, 1)), Gains(motor_tau=tau), sim, dtype=jnp.float64)
        x = np.asarray(x)
    t = dt * np.arange(steps + 1)
    v = np.concatenate([[0.0], x[:, 5]])
    mean_thrust = m * (np.diff(v) / dt + G)
    exact = m * (G + a) - m * a * tau / dt * (np.exp(-t[:-1] / tau) - np.exp(-t[1:] / tau))
    np.testing.assert_allclose(mean_thrust, exact, rtol=1e-5)
    np.testing.assert_allclose(x[:, 5], a * (t[1:] - tau * (1 - np.exp(-t[1:] / tau))), rtol=1e-9)
    np.testing.assert_allclose(x[:, 2] - 2.0, a * (t[1:] ** 2 / 2 - tau * t[1:] + tau**2 * (1 - np.exp(-t[1:] / tau))),
                               rtol=1e-9)
    measured_tau = (a * t[-1] - v[-1]) / a  # ∫(F_c - F) dt / (F_c - F_0), F_c - F_0 = m a; e^{-80} ≈ 0
    assert measured_tau == pytest.approx(tau, rel=1e-6)
    np.testing.assert_allclose(np.asarray(states.rotors[-1]), m * (G + a) / 4, rtol=1e-12)


def test_the_small_angle_response_matches_the_linearised_model():
    """Pitch θ: θ'' = -ω_n²(θ - θ_d) - 2ζω_n θ', θ_d = -a/g, ẍ = -g θ (no rotor lag), by an ODE solver."""
    a, omega, zeta = 0.05, 12.0, 0.7
    gains = Gains(att_omega=omega, att_zeta=zeta, motor_tau=0.0)
    sim = SimConfig.from_flat(plant="quadrotor", substeps=100)
    steps = 25
    with jax.enable_x64(True):
        _, (x, _, _) = fly(np.tile([a, 0.0, 0.0], (steps, 1)), gains, sim, dtype=jnp.float64)
    theta_d = -a / G

    def linear(_, s):
        theta, rate, _, v = s
        return [rate, -omega**2 * (theta - theta_d) - 2 * zeta * omega * rate, v, -G * theta]
    t = 0.1 * np.arange(1, steps + 1)
    ref = solve_ivp(linear, (0, t[-1]), [0.0, 0.0, 0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12).y
    np.testing.assert_allclose(np.asarray(x[:, 0]), ref[2], rtol=0.01, atol=1e-5)
    np.testing.assert_allclose(np.asarray(x[:, 3]), ref[3], rtol=0.01, atol=1e-5)


@pytest.mark.slow
def test_with_a_stiff_attitude_loop_its_trajectory_approaches_the_double_integrator():
    """The commands of a closed-loop double-integrator episode, replayed on quadrotors with ever stiffer
    attitude loops (a body of a thousandth of the inertia on rotors that never saturate, no lag):
    the flown path converges to the double integrator's."""
    scenario = one_obstacle_scenario(goal_x=10.0, obstacle_x=5.0, radius=0.8)
    ideal = rollout(scenario, Gains(), SimConfig.from_flat(method="basic", t_max=8.0), MPCConfig(horizon=10, iters=20))
    light = tuple(1e-3 * j for j in HUMMINGBIRD.inertia)
    strong = Quadrotor(dataclasses.replace(HUMMINGBIRD, inertia=light, f_max=1e4))
    misses = []
    for omega in (10.0, 40.0, 160.0):
        sim = SimConfig.from_flat(plant="quadrotor", substeps=int(omega))
        _, (x, _, diag) = fly(ideal.control, Gains(att_omega=omega, motor_tau=0.0), sim, start=ideal.position[0],
                              plant=strong)
        assert float(jnp.sum(diag["saturated_time"])) == 0.0
        misses.append(float(jnp.max(jnp.linalg.norm(x[:, :3] - ideal.position[1:], axis=-1))))
    # the miss shrinks as the loop's lag 2ζ/ω_n: four times stiffer, four times closer
    assert misses[0] > 3.5 * misses[1] > 12 * misses[2], misses
    assert misses[2] < 0.025, misses


def test_rotor_saturation_caps_the_forces_and_is_timed():
    """Asking for 30 m/s² upward needs 27 N; four rotors give 24 N: they saturate and the vehicle
    climbs at 24 N / m - g."""
    final, (x, states, diag) = fly(np.tile([0.0, 0.0, 30.0], (10, 1)), Gains(motor_tau=0.0))
    assert float(jnp.max(states.rotors)) <= HUMMINGBIRD.f_max * (1 + 1e-6)
    np.testing.assert_allclose(float(jnp.sum(diag["saturated_time"])), 1.0, rtol=1e-5)
    climb = (x[-1, 5] - x[-2, 5]) / 0.1
    np.testing.assert_allclose(float(climb), 4 * HUMMINGBIRD.f_max / HUMMINGBIRD.mass - G, rtol=1e-3)


def test_the_tilt_limit_holds_for_large_horizontal_commands():
    _, (_, _, diag) = fly(np.tile([30.0, 0.0, 0.0], (20, 1)), Gains(tilt_max=20.0))
    tilt = np.rad2deg(float(jnp.max(diag["tilt"])))
    assert 15.0 < tilt < 20.0 + 2.0  # the setpoint's limit plus the loop's overshoot


def test_the_rotation_stays_orthonormal_over_a_long_manoeuvring_flight():
    commands = 3.0 * np.sin(np.arange(3000)[:, None] * np.array([0.05, 0.031, 0.017]))
    final, _ = fly(commands, Gains(), SimConfig.from_flat(plant="quadrotor", substeps=10))
    r = rotation(final.attitude)
    np.testing.assert_allclose(np.asarray(r.T @ r), np.eye(3), atol=2e-6)
    np.testing.assert_allclose(float(jnp.linalg.det(r)), 1.0, atol=2e-6)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["att_omega", "att_zeta", "motor_tau", "tilt_max"])
def test_gradients_through_the_plant_match_central_differences(name):
    commands = np.stack([2.0 * np.sin(0.4 * np.arange(15)), 1.5 * np.cos(0.3 * np.arange(15)),
                         0.5 * np.ones(15)], axis=1)
    with jax.enable_x64(True):
        base = Gains(tilt_max=10.0).as_arrays(jnp.float64)  # the limit binds on some steps

        def final(value):
            _, (x, _, _) = fly(commands, base.replace(**{name: value}), dtype=jnp.float64)
            return jnp.sum(x[-1] * jnp.array([1.0, -0.5, 0.3, 0.7, 0.2, -0.4]))
        at = float(base[name])
        grad = float(jax.grad(final)(jnp.float64(at)))
        h = 1e-5 * max(at, 1.0)
        fd = (float(final(jnp.float64(at + h))) - float(final(jnp.float64(at - h)))) / (2 * h)
    assert abs(grad) > 1e-6
    np.testing.assert_allclose(grad, fd, rtol=1e-4, atol=1e-9)


@pytest.mark.slow
def test_a_closed_loop_gradient_through_the_quadrotor_matches_central_differences():
    """What ``jaxapf tune`` differentiates: a planner gain through MPC and quadrotor (float64)."""
    with jax.enable_x64(True):
        scenario = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64) if x.dtype == jnp.float32 else x,
                                          one_obstacle_scenario(goal_x=6.0, obstacle_x=3.0, radius=0.6))
        sim = SimConfig.from_flat(method="basic", plant="quadrotor", t_max=3.0)
        mpc = MPCConfig(horizon=6, iters=10)

        def final(k_rep):
            traj = rollout(scenario, Gains(k_rep=k_rep).as_arrays(jnp.float64), sim, mpc)
            return jnp.sum(traj.position[-1] * jnp.array([1.0, 0.7, 0.3]))
        grad = float(jax.grad(final)(jnp.float64(10.0)))
        fd = (float(final(jnp.float64(10.0 + 1e-4))) - float(final(jnp.float64(10.0 - 1e-4)))) / 2e-4
    assert abs(grad) > 1e-6
    np.testing.assert_allclose(grad, fd, rtol=1e-4)

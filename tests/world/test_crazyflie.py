"""The Crazyflie plants (drone-models): each identified response against its published parameters, the
command mapping, the onboard controller, and one-line errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from jaxapf import Gains, SimConfig
from jaxapf.validation import ConfigError
from jaxapf.world import PLANTS
from jaxapf.world.crazyflie import FIDELITIES, airframe_parameters


def _fly(plant_name: str, accel, steps: int, substeps: int = 10, airframe: str = "cf2x_L250"):
    """The plant's states after each of ``steps`` control steps under a constant command ``accel``, float64."""
    plant = PLANTS.get(plant_name, "plant")
    sim = SimConfig.from_flat(plant=plant_name, substeps=substeps, airframe=airframe)
    gains = Gains()
    states, extras = [], []
    with jax.enable_x64(True):
        state = plant.init(jnp.zeros(3, jnp.float64), gains, sim)
        step = jax.jit(lambda s: plant.step(s, jnp.asarray(accel, jnp.float64), jnp.zeros(3, jnp.float64), gains, sim))
        for _ in range(steps):
            state, extra = step(state)
            states.append(jax.device_get(state))
            extras.append(jax.device_get(extra))
    return states, extras


def _roll(q):
    x, y, z, w = np.asarray(q)
    return np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))


@pytest.mark.parametrize("fidelity", ["so_rpy", pytest.param("so_rpy_rotor", marks=pytest.mark.slow),
                                      pytest.param("so_rpy_rotor_drag", marks=pytest.mark.slow)])
def test_a_roll_command_follows_the_published_second_order_response(fidelity):
    """Roll alone: the identified ``φ'' = a φ + b φ' + c u`` (rpy_coef, rpy_rates_coef, cmd_rpy_coef)
    with the plant's command ``u = -asin(b3_y)``, solved exactly by a matrix exponential, to RK4's error."""
    accel = np.array([0.0, -1.0, 0.0])
    states, _ = _fly(f"crazyflie_{fidelity}", accel, steps=15)
    p = airframe_parameters(fidelity, "cf2x_L250")
    a, b, c = p["rpy_coef"][0], p["rpy_rates_coef"][0], p["cmd_rpy_coef"][0]
    w = accel + np.array([0.0, 0.0, 9.81])
    u = -np.arcsin((w / np.linalg.norm(w))[1])
    system = np.array([[0.0, 1.0, 0.0], [a, b, c * u], [0.0, 0.0, 0.0]])  # (φ, φ', 1)
    for k, s in enumerate(states, start=1):
        exact = (scipy.linalg.expm(system * 0.1 * k) @ np.array([0.0, 0.0, 1.0]))[0]
        assert _roll(s.quaternion) == pytest.approx(exact, abs=2e-6)
    assert _roll(states[-1].quaternion) == pytest.approx(-c / a * u, rel=0.02)  # the fitted steady state


@pytest.mark.parametrize("fidelity", ["so_rpy_rotor", pytest.param("so_rpy_rotor_drag", marks=pytest.mark.slow)])
def test_the_thrust_follows_its_identified_lag(fidelity):
    """A vertical command keeps the body level; the thrust state follows ``T' = (cmd - T)/τ``
    (thrust_time_coef) from hover, exactly ``cmd + (T0 - cmd) e^{-t/τ}``."""
    p = airframe_parameters(fidelity, "cf2x_L250")
    m, tau = float(p["mass"]), float(p["thrust_time_coef"])
    states, _ = _fly(f"crazyflie_{fidelity}", [0.0, 0.0, 1.0], steps=5)
    hover = m * 9.81 / float(p["cmd_f_coef"])
    command = m * (9.81 + 1.0)
    for k, s in enumerate(states, start=1):
        assert float(s.rotors[0]) == pytest.approx(command + (hover - command) * np.exp(-0.1 * k / tau), rel=1e-7)
        assert np.abs(np.asarray(s.quaternion)[:3]).max() < 1e-12


def test_the_fitted_thrust_gain_is_what_the_vehicle_feels():
    """so_rpy applies ``cmd_f_coef`` of the commanded thrust at once: hovering on ``m g`` it sinks at
    ``(1 - cmd_f_coef) g``, as the published fit says, and the MPC's box is not the vehicle's."""
    p = airframe_parameters("so_rpy", "cf2x_L250")
    states, _ = _fly("crazyflie_so_rpy", [0.0, 0.0, 0.0], steps=1)
    assert float(states[0].velocity[2]) == pytest.approx(-(1 - float(p["cmd_f_coef"])) * 9.81 * 0.1, rel=1e-9)


@pytest.mark.slow
def test_the_onboard_controller_holds_hover_and_tracks_a_tilt():
    """crazyflie_first_principles: the Mellinger controller of drone-controllers on the motor-speed model
    keeps a hover within millimetres and settles on the commanded tilt, rotors within their limits."""
    states, extras = _fly("crazyflie_first_principles", [0.0, 0.0, 0.0], steps=20)
    assert np.abs(np.asarray(states[-1].position)).max() < 0.01
    p = airframe_parameters("first_principles", "cf2x_L250")
    states, extras = _fly("crazyflie_first_principles", [0.5, 0.0, 0.0], steps=20)
    assert float(extras[-1]["tilt"]) == pytest.approx(np.arctan(0.5 / 9.81), rel=0.05)
    assert float(states[-1].velocity[0]) > 0.5 * 0.5 * 2.0  # it accelerates the way it was told
    rpm = np.asarray([s.rotors for s in states])
    a, b, c = p["rpm2thrust"]
    force = a + b * rpm + c * rpm**2
    assert force.min() >= float(p["thrust_min"]) * 0.999 and force.max() <= float(p["thrust_max"]) * 1.001


@pytest.mark.slow
def test_a_command_past_the_thrust_limit_saturates():
    """The L250 lifts at most 4 × 0.12 N (thrust-to-weight about 1.5): asking for 8 m/s² up is clipped
    and counted, every fidelity."""
    for fidelity in FIDELITIES:
        _, extras = _fly(f"crazyflie_{fidelity}", [0.0, 0.0, 8.0], steps=2)
        assert float(extras[-1]["saturated_time"]) == pytest.approx(0.1), fidelity


@pytest.mark.slow
def test_every_airframe_flies_and_a_bad_one_is_one_line():
    for airframe in ("cf2x_P250", "cf2x_T350", "cf21B_500"):
        states, _ = _fly("crazyflie_so_rpy_rotor_drag", [0.3, 0.0, 0.0], steps=3, airframe=airframe)
        assert np.isfinite(np.asarray(states[-1].position)).all() and float(states[-1].velocity[0]) > 0
    with pytest.raises(ConfigError, match="sim.airframe = 'cf3'"):
        SimConfig.from_flat(airframe="cf3")


def test_without_drone_models_the_plant_names_the_extra(monkeypatch):
    import builtins

    from jaxapf.world import crazyflie

    real = builtins.__import__

    def blocked(name, *args, **kwargs):
        if name.startswith("drone_models"):
            raise ImportError(name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", blocked)
    with pytest.raises(ConfigError, match=r"pip install 'jaxapf\[vehicles\]'"):
        crazyflie.load_model("so_rpy", "cf2x_L250")


def _paired_flight(h: float, seconds: float = 1.0):
    """The Crazyflie's rigid body flown by jaxapf's quadrotor equations (``rigid_body_step``, paper frame)
    and by ``drone_models.first_principles`` (RK4, z up) under the same rotor speeds, held per sub-step:
    drone-models turns them into the wrench (its own thrust and torque curves, X mixing); drag and
    propeller inertia are set to zero, as jaxapf's quadrotor has neither. Positions (z up) over the flight."""
    from jaxapf.world.crazyflie import CrazyflieState, _quaternion_rate, load_model
    from jaxapf.world.quadrotor import FRAME, QuadrotorState, rigid_body_step

    p = airframe_parameters("first_principles", "cf2x_L250")
    model = load_model("first_principles", "cf2x_L250")
    model = jax.tree_util.Partial(model.func, **(model.keywords | {"drag_matrix": np.zeros((3, 3)),
                                                                   "prop_inertia": 0.0}))
    mass, inertia = float(p["mass"]), np.diag(np.asarray(p["J"], np.float64))
    hover = (-p["rpm2thrust"][1] + np.sqrt(p["rpm2thrust"][1] ** 2 + 4 * p["rpm2thrust"][2] * mass * 9.81 / 4)) / (
        2 * p["rpm2thrust"][2])
    steps = int(round(seconds / h))
    with jax.enable_x64(True):
        def rpm(k):
            t = k * h
            return hover * (1 + 0.02 * jnp.array([jnp.sin(3 * t), jnp.cos(2 * t), -jnp.sin(5 * t), 0.5 * jnp.cos(t)]))

        def wrench(cmd):  # the body wrench drone-models makes of `cmd`, read off at rest and level
            z = jnp.zeros(3)
            d = model(z, jnp.array([0.0, 0.0, 0.0, 1.0]), z, z, cmd, None)
            return mass * (d[2][2] + 9.81), jnp.asarray(inertia) * d[3]

        def theirs(s, k):
            cmd = rpm(k)

            def f(x):
                d = model(x.position, x.quaternion, x.velocity, x.rates, cmd, None)
                return CrazyflieState(d[0], _quaternion_rate(x.quaternion, x.rates), d[2], d[3], x.rotors, x.controller)

            def moved(a, b, c):
                return jax.tree_util.tree_map(lambda u, du: u + c * h * du, a, b)

            k1 = f(s)
            k2 = f(moved(s, k1, 0.5))
            k3 = f(moved(s, k2, 0.5))
            k4 = f(moved(s, k3, 1.0))
            s = jax.tree_util.tree_map(lambda u, a, b, c, d: u + h / 6 * (a + 2 * b + 2 * c + d), s, k1, k2, k3, k4)
            return s._replace(quaternion=s.quaternion / jnp.linalg.norm(s.quaternion)), s.position

        def ours(s, k):
            thrust, torque = wrench(rpm(k))
            body = rigid_body_step(s, jnp.concatenate([thrust[None], FRAME * torque]), thrust, h, mass,
                                   jnp.asarray(inertia), jnp.array([0.0, 0.0, 9.81]), jnp.zeros(3))
            return QuadrotorState(*body, s.rotors), body[0] * FRAME

        z = jnp.zeros(3)
        start_theirs = CrazyflieState(z, jnp.array([0.0, 0.0, 0.0, 1.0]), z, z, jnp.zeros(0), jnp.zeros(0))
        start_ours = QuadrotorState(z, z, jnp.array([1.0, 0.0, 0.0, 0.0]), z, jnp.zeros(4))
        ks = jnp.arange(steps)
        a = jax.jit(lambda: jax.lax.scan(theirs, start_theirs, ks)[1])()
        b = jax.jit(lambda: jax.lax.scan(ours, start_ours, ks)[1])()
        return np.asarray(a), np.asarray(b)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:Rotor velocity not provided")
def test_jaxapfs_quadrotor_with_the_crazyflies_parameters_flies_as_drone_models_first_principles():
    """Same rotor speeds, same Crazyflie: jaxapf's rigid body (eq. 1 and 3, first order in the sub-step)
    and drone-models' first-principles model (RK4) fly the same path; the gap is integration error:
    0.19 mm after a second of a tumbling flight of about 2 m at h = 1 ms, halving with the sub-step."""
    a1, b1 = _paired_flight(1e-3)
    a2, b2 = _paired_flight(5e-4)
    gap1, gap2 = np.abs(a1 - b1).max(), np.abs(a2 - b2).max()
    assert np.abs(a1).max() > 0.05  # it moved
    assert gap1 < 1e-3
    assert gap2 == pytest.approx(gap1 / 2, rel=0.1)

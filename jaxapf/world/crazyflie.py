r"""The Crazyflie 2.x as identified from real flights: the models of ``drone-models`` (learnsyslab) as plants.

Four plants, one per fidelity, for the airframe ``sim.airframe`` (:data:`AIRFRAMES`): ``crazyflie_so_rpy``
(the fitted second-order attitude response, thrust at once), ``crazyflie_so_rpy_rotor`` (plus the thrust's
identified lag), ``crazyflie_so_rpy_rotor_drag`` (plus the identified body drag) and
``crazyflie_first_principles`` (four motors driven by the onboard Mellinger controller of
``drone-controllers``). The MPC keeps planning with the double integrator; its acceleration becomes the
vehicle's command through the quadrotor plant's mapping, and each model's own time derivative is integrated
by classical Runge–Kutta over ``sim.substeps`` sub-steps per control step. The models, the command and its
limits: docs/spec.md §1, "Vehicles identified from real flights".

Needs the ``vehicles`` extra (``pip install 'jaxapf[vehicles]'``). ``drone-models`` refuses to load after
SciPy was imported without ``SCIPY_ARRAY_API=1``; importing jaxapf sets it.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ..config import AIRFRAMES
from ..datatypes import safe_norm
from ..validation import ConfigError
from .base import Plant, register_plant
from .double_integrator import discrete_matrices
from .quadrotor import Quadrotor, attitude_setpoint, limit_thrust, quaternion_product, rotation

__all__ = ["AIRFRAMES", "FIDELITIES", "Crazyflie", "CrazyflieState", "load_model", "airframe_parameters"]

#: The fidelities, lowest first, and the state each keeps beside the rigid body (rotor speeds in RPM, the
#: lagged thrust in N, or none).
FIDELITIES = {"so_rpy": 0, "so_rpy_rotor": 1, "so_rpy_rotor_drag": 1, "first_principles": 4}


def _drone_models():
    try:
        import drone_models
    except ImportError:
        raise ConfigError("the crazyflie plants need drone-models: pip install 'jaxapf[vehicles]'") from None
    except RuntimeError:  # SciPy imported before jaxapf without SCIPY_ARRAY_API=1
        raise ConfigError("the crazyflie plants need drone-models, which must load before SciPy: import jaxapf "
                          "first, or set SCIPY_ARRAY_API=1") from None
    return drone_models


@functools.cache
def airframe_parameters(fidelity: str, airframe: str) -> dict[str, Any]:
    """The published parameters (numpy) of ``airframe`` for the model ``fidelity``: its own
    coefficients and the airframe's physical ones (``drone_models.core.load_params``)."""
    _drone_models()
    from drone_models.core import load_params

    return load_params(fidelity, airframe)


@functools.cache
def _mellinger(airframe: str):
    """The Crazyflie's onboard Mellinger attitude controller and power distribution (``drone-controllers``)
    bound to ``airframe``'s published gains."""
    _drone_models()
    try:
        import drone_controllers as dc
        from drone_controllers.mellinger.control import force_torque2rotor_vel
    except ImportError:
        raise ConfigError("crazyflie_first_principles needs drone-controllers: "
                          "pip install 'jaxapf[vehicles]'") from None
    return (dc.parametrize(dc.available_controller["mellinger_attitude2force_torque"], airframe),
            dc.parametrize(force_torque2rotor_vel, airframe))


def load_model(fidelity: str, airframe: str):
    """``drone-models``' dynamics function of ``fidelity`` bound to ``airframe``'s parameters:
    ``f(pos, quat, vel, ang_vel, cmd, rotor_vel) -> (pos_dot, quat_dot, vel_dot, ang_vel_dot, rotor_vel_dot)``."""
    dm = _drone_models()
    return dm.parametrize(dm.available_models[fidelity], airframe)


class CrazyflieState(NamedTuple):
    """Position, quaternion ``(x, y, z, w)`` (body to world), velocity, body rates, the rotor state of
    the fidelity (:data:`FIDELITIES`) and, for the first-principles model, the onboard attitude
    controller's (the last body rates and the integral of the attitude error; empty otherwise)."""

    position: Array
    quaternion: Array
    velocity: Array
    rates: Array
    rotors: Array
    controller: Array


def _matrix(q: Array) -> Array:
    return rotation(jnp.concatenate([q[3:], q[:3]]))


def _quaternion_rate(q: Array, rates: Array) -> Array:
    """``q̇ = ½ q ⊗ (0, ω)`` of a quaternion ``(x, y, z, w)`` under body rates ``ω``. (``drone-models``'
    own ``quat_dot`` is not meant for integration, its docstring says; it assumes ``w`` first.)"""
    p = 0.5 * quaternion_product(jnp.concatenate([q[3:], q[:3]]), jnp.concatenate([jnp.zeros(1, q.dtype), rates]))
    return jnp.concatenate([p[1:], p[:1]])


@dataclasses.dataclass(frozen=True)
class Crazyflie(Plant):
    """A Crazyflie 2.x model of ``drone-models`` at one fidelity (module docstring)."""

    fidelity: str = "so_rpy_rotor_drag"

    metrics: ClassVar = Quadrotor.metrics

    @property
    def gains(self) -> tuple:
        """``tilt_max`` (the attitude loops are the vehicle's own: fitted, or the onboard controller)."""
        return tuple(g for g in Quadrotor.gains if g.name == "tilt_max")

    def _params(self, sim: Any) -> dict[str, Any]:
        return airframe_parameters(self.fidelity, sim.vehicle.airframe)

    def init(self, start: Array, gains: Any, sim: Any) -> CrazyflieState:
        dtype = start.dtype
        p = self._params(sim)
        hover = float(p["mass"]) * 9.81
        kept = FIDELITIES[self.fidelity]
        if kept == 4:  # motor speeds at hover
            rotors = jnp.full((4,), self._rpm(hover / 4, p), dtype)
        elif kept == 1:  # the lagged thrust at hover
            rotors = jnp.full((1,), (hover - float(p.get("acc_coef", 0.0))) / float(p.get("cmd_f_coef", 1.0)), dtype)
        else:
            rotors = jnp.zeros(0, dtype)
        zero = jnp.zeros(3, dtype)
        controller = jnp.zeros(6 if self.fidelity == "first_principles" else 0, dtype)
        return CrazyflieState(start, jnp.array([0.0, 0.0, 0.0, 1.0], dtype), zero, zero, rotors, controller)

    def kinematics(self, state: CrazyflieState) -> Array:
        return jnp.concatenate([state.position, state.velocity])

    def linear_model(self, dt: float, dtype: Any) -> tuple[Array, Array]:
        return discrete_matrices(dt, 1, dtype)

    @staticmethod
    def _rpm(force: Any, p: dict[str, Any]) -> Any:
        """The motor speed [RPM] giving ``force`` [N] on the thrust curve ``a + b ω + c ω²``."""
        a, b, c = (float(x) for x in p["rpm2thrust"])
        return (-b + jnp.sqrt(b * b + 4 * c * (force - a))) / (2 * c)

    def _command(self, state: CrazyflieState, w: Array, target: Array, sim: Any, p: dict[str, Any]
                 ) -> tuple[Array, Array, Array]:
        """The model's command for this sub-step, whether it was clipped, and the controller's next state."""
        dtype = w.dtype
        r = _matrix(state.quaternion)
        thrust = float(p["mass"]) * jnp.dot(w, r[:, 2])
        lo, hi = float(p["thrust_min"]), float(p["thrust_max"])
        b3 = target[:, 2]
        roll, pitch = -jnp.arcsin(jnp.clip(b3[1], -1.0, 1.0)), jnp.arctan2(b3[0], b3[2])
        clipped = jnp.clip(thrust, 4 * lo, 4 * hi)
        attitude = jnp.stack([roll, pitch, jnp.zeros((), dtype), clipped])
        if self.fidelity != "first_principles":
            return attitude, clipped != thrust, state.controller
        # the Crazyflie's onboard Mellinger attitude controller at the sub-step rate, then its power
        # distribution (drone-controllers), each rotor's force within [thrust_min, thrust_max]
        attitude_loop, distribution = _mellinger(sim.vehicle.airframe)
        force, torque, integral = attitude_loop(state.position, state.quaternion, state.velocity, state.rates,
                                                attitude, state.controller[:3], (state.controller[3:],),
                                                ctrl_freq=sim.vehicle.substeps / sim.episode.dt)
        rpm = distribution(force, torque).astype(dtype)
        bounds = jnp.asarray([self._rpm(lo, p), self._rpm(hi, p)], dtype)
        saturated = jnp.any((rpm <= bounds[0] * (1 + 1e-6)) | (rpm >= bounds[1] * (1 - 1e-6)))
        return rpm, saturated | (clipped != thrust), jnp.concatenate([state.rates, integral])

    def step(self, state: CrazyflieState, accel: Array, disturbance: Array, gains: Any, sim: Any
             ) -> tuple[CrazyflieState, dict[str, Array]]:
        dtype = accel.dtype
        p = self._params(sim)
        model = load_model(self.fidelity, sim.vehicle.airframe)
        h = sim.episode.dt / sim.vehicle.substeps
        mass = float(p["mass"])
        w = limit_thrust(accel + jnp.array([0.0, 0.0, 9.81], dtype), 9.81, gains.tilt_max)
        target = attitude_setpoint(w)
        push = mass * disturbance  # a force [N] on the centre of mass
        lagged = FIDELITIES[self.fidelity] > 0

        def derivative(s: CrazyflieState, cmd: Array) -> CrazyflieState:
            d = model(s.position, s.quaternion, s.velocity, s.rates, cmd, s.rotors if lagged else None, push)
            return CrazyflieState(d[0], _quaternion_rate(s.quaternion, s.rates), d[2], d[3],
                                  d[4] if lagged else jnp.zeros_like(s.rotors), jnp.zeros_like(s.controller))

        def substep(s: CrazyflieState, _) -> tuple[CrazyflieState, tuple[Array, Array]]:
            cmd, saturated, controller = self._command(s, w, target, sim, p)

            def moved(a: CrazyflieState, k: CrazyflieState, c: float) -> CrazyflieState:
                return jax.tree_util.tree_map(lambda x, dx: x + c * h * dx, a, k)

            k1 = derivative(s, cmd)
            k2 = derivative(moved(s, k1, 0.5), cmd)
            k3 = derivative(moved(s, k2, 0.5), cmd)
            k4 = derivative(moved(s, k3, 1.0), cmd)
            new = jax.tree_util.tree_map(lambda x, a, b, c, d: x + h / 6 * (a + 2 * b + 2 * c + d), s, k1, k2, k3, k4)
            new = new._replace(quaternion=new.quaternion / safe_norm(new.quaternion), controller=controller)
            r = _matrix(new.quaternion)
            tilt = jnp.arctan2(safe_norm(r[:2, 2]), r[2, 2])
            return new, (tilt, saturated)

        state, (tilt, saturated) = jax.lax.scan(substep, state, None, length=sim.vehicle.substeps)
        return state, {"tilt": jnp.max(tilt), "saturated_time": h * jnp.sum(saturated).astype(dtype)}


for _fidelity in FIDELITIES:
    register_plant(f"crazyflie_{_fidelity}", Crazyflie(_fidelity))

r"""The quadrotor of the paper's section 2.1 (eq. 1–3) as a plant, with its inner attitude loop.

The MPC keeps planning with the double integrator; this plant realises its acceleration command
through a rigid body with four rotors at ``sim.vehicle.substeps`` sub-steps per control step: the thrust
vector the command asks for (within ``tilt_max``), Lee, Leok and McClamroch's geometric attitude loop
(``att_omega``, ``att_zeta``), the rotors' allocation, saturation and exactly integrated lag
(``motor_tau``), and the rigid body in the paper's z-down frame with a unit quaternion (so ``R`` is a
proper rotation, unlike the paper's printed eq. 2). It reports ``tilt`` and ``saturated_time`` per step.
The reference vehicle is the AscTec Hummingbird as RotorS models it (:data:`HUMMINGBIRD`). The stages'
equations, the frames and the parameters: docs/spec.md, section 1. The helpers shared with the
Crazyflie plants (:mod:`jaxapf.world.crazyflie`) are :func:`limit_thrust`, :func:`attitude_setpoint`,
:func:`attitude_torque` and :func:`rigid_body_step`.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..datatypes import safe_norm
from ..gains import GainSpec
from ..metrics import Metric
from .base import Plant, register_plant
from .double_integrator import discrete_matrices

__all__ = ["QuadrotorState", "Vehicle", "HUMMINGBIRD", "Quadrotor", "rotation", "quaternion_product", "FRAME",
           "limit_thrust", "attitude_setpoint", "attitude_torque", "rigid_body_step"]

#: jaxapf's world frame (z up) to the paper's (z down): a turn by π about x.
FRAME = np.array([1.0, -1.0, -1.0])


@dataclasses.dataclass(frozen=True)
class Vehicle:
    """Physical parameters of a quadrotor (SI units)."""

    name: str
    mass: float
    inertia: tuple[float, float, float]
    arm: float
    torque_coefficient: float
    f_max: float
    gravity: float = 9.81

    def allocation(self) -> np.ndarray:
        """Eq. 3's map (4, 4) from rotor forces to ``(F_T, τ_x, τ_y, τ_z)``."""
        length, c = self.arm, self.torque_coefficient
        return np.array([[1.0, 1.0, 1.0, 1.0], [0.0, length, 0.0, -length], [length, 0.0, -length, 0.0],
                         [-c, c, -c, c]])


HUMMINGBIRD = Vehicle("AscTec Hummingbird (RotorS)", mass=0.68, inertia=(0.007, 0.007, 0.012), arm=0.17,
                      torque_coefficient=0.016, f_max=8.54858e-6 * 838.0**2)


class QuadrotorState(NamedTuple):
    """Position and velocity in the paper's frame, attitude quaternion ``(w, x, y, z)`` (body to
    world), body rates and the four rotor forces."""

    position: Array
    velocity: Array
    attitude: Array
    rates: Array
    rotors: Array


def rotation(q: Array) -> Array:
    """The rotation matrix (3, 3) of a unit quaternion ``q = (w, x, y, z)`` (Hamilton convention)."""
    w, x, y, z = q
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
        jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
        jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
    ])


def quaternion_product(a: Array, b: Array) -> Array:
    """Hamilton product ``a ⊗ b``."""
    return jnp.concatenate([a[:1] * b[:1] - jnp.dot(a[1:], b[1:]),
                            a[0] * b[1:] + b[0] * a[1:] + jnp.cross(a[1:], b[1:])])


def _vee(m: Array) -> Array:
    return jnp.stack([m[2, 1], m[0, 2], m[1, 0]])


def rigid_body_step(s: QuadrotorState, wrench: Array, thrust_ramp: Array, h: float, mass: float, inertia: Array,
                    gravity: Array, push: Array) -> tuple[Array, Array, Array, Array]:
    """Position, velocity, attitude and body rates one sub-step ``h`` on (module docstring, step 4): eq. 3
    for the rates (an Euler step under the body torque ``wrench[1:]``), the attitude turned by the exact
    rotation of the new rates, eq. 1 for the translation under the thrust ``wrench[0]`` (its position
    weight ``thrust_ramp``) along the start-of-sub-step body axis, gravity and the ``push`` (paper frame)."""
    r = rotation(s.attitude)
    rates = s.rates + h * (wrench[1:] - jnp.cross(s.rates, inertia * s.rates)) / inertia
    half = 0.5 * h * rates
    angle = safe_norm(half)
    turn = jnp.concatenate([jnp.cos(angle)[None], half * (jnp.sin(angle) / angle)])
    attitude = quaternion_product(s.attitude, turn)
    attitude = attitude / safe_norm(attitude)
    acc = gravity - (wrench[0] / mass) * r[:, 2] + push
    acc_ramp = gravity - (thrust_ramp / mass) * r[:, 2] + push
    position = s.position + h * s.velocity + 0.5 * h * h * acc_ramp
    velocity = s.velocity + h * acc
    return position, velocity, attitude, rates


def limit_thrust(w: Array, gravity: float, tilt_max: Array) -> Array:
    """The thrust per unit mass ``w`` (its component 2 against gravity) with that component at least
    ``g/5`` (a rotor cannot pull down) and the horizontal part shortened until ``w`` lies within
    ``tilt_max`` [deg] of the vertical (module docstring, step 1)."""
    w_z = jnp.maximum(w[2], 0.2 * gravity)
    horizontal = safe_norm(w[:2])
    scale = jnp.minimum(1.0, jnp.tan(jnp.deg2rad(tilt_max)) * w_z / horizontal)
    return jnp.concatenate([w[:2] * scale, w_z[None]])


def attitude_setpoint(w: Array) -> Array:
    """``R_d`` (3, 3): the attitude whose body z axis points along ``w``, with zero yaw."""
    b3 = w / safe_norm(w)
    b2 = jnp.cross(b3, jnp.array([1.0, 0.0, 0.0], w.dtype))
    b2 = b2 / safe_norm(b2)
    return jnp.stack([jnp.cross(b2, b3), b2, b3], axis=1)


def attitude_torque(r: Array, target: Array, rates: Array, inertia: Array, gains: Any) -> Array:
    """The geometric SO(3) controller (Lee, Leok and McClamroch 2010; module docstring, step 2): the body
    torque taking the attitude ``r`` with body rates ``rates`` to ``target``, for a diagonal ``inertia``."""
    e_r = 0.5 * _vee(target.T @ r - r.T @ target)
    k_r = inertia * gains.att_omega**2
    k_w = inertia * 2 * gains.att_zeta * gains.att_omega
    return -k_r * e_r - k_w * rates + jnp.cross(rates, inertia * rates)


@dataclasses.dataclass(frozen=True)
class Quadrotor(Plant):
    """The paper's quadrotor (eq. 1–3): geometric attitude loop, rotor limits and lag, inner sub-steps."""

    vehicle: Vehicle = HUMMINGBIRD

    gains: ClassVar[tuple[GainSpec, ...]] = (
        GainSpec("att_omega", 15.0, low=0.0, low_open=True, unit="rad/s", symbol="ω_n", tunable=False,
                 doc="natural frequency of the attitude loop"),
        GainSpec("att_zeta", 0.9, low=0.0, low_open=True, symbol="ζ", tunable=False,
                 doc="damping ratio of the attitude loop"),
        GainSpec("motor_tau", 0.0125, low=0.0, unit="s", symbol="τ_m", tunable=False,
                 doc="time constant of the rotors' first-order lag (0: none)"),
        GainSpec("tilt_max", 35.0, low=0.0, high=90.0, low_open=True, high_open=True, unit="deg", symbol="θ_max",
                 tunable=False, doc="largest tilt of the thrust axis the attitude setpoint may ask for"),
    )
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric("max_tilt", lambda ctx: jnp.rad2deg(ctx.extra("tilt", jnp.max)), unit="deg", higher_is_better=False,
               margin=2.0, doc="largest tilt of the thrust axis (0 for a plant without attitude)"),
        Metric("saturation_time", lambda ctx: ctx.extra("saturated_time"), unit="s", higher_is_better=False,
               margin=0.1, doc="time during which a rotor command was clipped (0 for a plant without rotors)"),
    )

    def init(self, start: Array, gains: Any, sim: Any) -> QuadrotorState:
        dtype = start.dtype
        hover = self.vehicle.mass * self.vehicle.gravity / 4
        return QuadrotorState(start * FRAME.astype(dtype), jnp.zeros(3, dtype), jnp.array([1.0, 0.0, 0.0, 0.0], dtype),
                              jnp.zeros(3, dtype), jnp.full((4,), hover, dtype))

    def kinematics(self, state: QuadrotorState) -> Array:
        frame = FRAME.astype(state.position.dtype)
        return jnp.concatenate([state.position * frame, state.velocity * frame])

    def linear_model(self, dt: float, dtype: Any) -> tuple[Array, Array]:
        return discrete_matrices(dt, 1, dtype)

    def thrust_setpoint(self, accel: Array, gains: Any) -> Array:
        """``w``, the thrust per unit mass the body should produce along its ``-z`` for ``accel``
        (paper frame), after the vertical floor and the tilt limit (module docstring, step 1)."""
        g = self.vehicle.gravity
        return limit_thrust(jnp.array([0.0, 0.0, g], accel.dtype) - accel, g, gains.tilt_max)

    def step(self, state: QuadrotorState, accel: Array, disturbance: Array, gains: Any, sim: Any
             ) -> tuple[QuadrotorState, dict[str, Array]]:
        vehicle, dtype = self.vehicle, accel.dtype
        frame = FRAME.astype(dtype)
        h = sim.episode.dt / sim.vehicle.substeps
        inertia = jnp.asarray(vehicle.inertia, dtype)
        mix = jnp.asarray(vehicle.allocation(), dtype)
        unmix = jnp.asarray(np.linalg.inv(vehicle.allocation()), dtype)
        gravity = jnp.array([0.0, 0.0, vehicle.gravity], dtype)
        push = disturbance * frame
        w = self.thrust_setpoint(accel * frame, gains)
        target = attitude_setpoint(w)
        # first-order lag F' = (c - F)/τ under a command c held over the sub-step: F(s) = c + (F_0 - c) e^{-s/τ}.
        # The end value takes `lag`; the body feels the force's exact mean over the sub-step (`mean`, for the
        # rates and the velocity) and its weighted mean 2/h² ∫(h - s) F ds (`ramp`, for the position).
        positive = gains.motor_tau > 0
        tau = jnp.maximum(gains.motor_tau, 1e-9)
        lag = jnp.where(positive, jnp.exp(-h / tau), 0.0)
        mean = jnp.where(positive, -(tau / h) * jnp.expm1(-h / tau), 0.0)
        ramp = jnp.where(positive, 2.0 * (tau / h) * (1.0 - mean), 0.0)

        def substep(s: QuadrotorState, _) -> tuple[QuadrotorState, tuple[Array, Array]]:
            r = rotation(s.attitude)
            torque = attitude_torque(r, target, s.rates, inertia, gains)
            thrust = vehicle.mass * jnp.dot(w, r[:, 2])
            command = unmix @ jnp.concatenate([thrust[None], torque])
            clipped = jnp.clip(command, 0.0, vehicle.f_max)
            rotors = clipped + (s.rotors - clipped) * lag
            wrench = mix @ (clipped + (s.rotors - clipped) * mean)
            thrust_ramp = jnp.sum(clipped + (s.rotors - clipped) * ramp)
            body = rigid_body_step(s, wrench, thrust_ramp, h, vehicle.mass, inertia, gravity, push)
            tilt = jnp.arctan2(safe_norm(r[:2, 2]), r[2, 2])
            saturated = jnp.any(clipped != command)
            return QuadrotorState(*body, rotors), (tilt, saturated)

        state, (tilt, saturated) = jax.lax.scan(substep, state, None, length=sim.vehicle.substeps)
        return state, {"tilt": jnp.max(tilt), "saturated_time": h * jnp.sum(saturated).astype(dtype)}


register_plant("quadrotor", Quadrotor())

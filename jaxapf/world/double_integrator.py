r"""Outer-loop vehicle model: the discrete double integrator (paper eq. 4–7, SPEC 1).

.. math::
   x(k+1) = A x(k) + B a(k), \quad
   A = \begin{pmatrix} I & \Delta t\, I \\ 0 & I \end{pmatrix}, \quad
   B = \begin{pmatrix} \tfrac12 \Delta t^2 I \\ \Delta t\, I \end{pmatrix}

with state ``x = [p, v]`` and acceleration input ``a``. The update is exact for a piecewise-constant
acceleration, so the plant integrates the applied control without discretisation error.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax.numpy as jnp
from jax import Array

from .base import Plant, register_plant

__all__ = ["discrete_matrices", "step", "DoubleIntegrator"]


def discrete_matrices(dt: float, dim: int = 3, dtype=None) -> tuple[Array, Array]:
    """``(A, B)`` of the double integrator in ``dim`` axes: shapes (2 dim, 2 dim), (2 dim, dim).

    ``dim = 3`` is the full vehicle (paper eq. 7); ``dim = 1`` is one axis, which the MPC uses since
    the problem separates per axis.
    """
    dtype = dtype or jnp.result_type(float)
    eye = jnp.eye(dim, dtype=dtype)
    zero = jnp.zeros((dim, dim), dtype)
    a = jnp.block([[eye, dt * eye], [zero, eye]])
    b = jnp.concatenate([0.5 * dt * dt * eye, dt * eye], axis=0)
    return a, b


def step(x: Array, a: Array, dt: float) -> Array:
    """One exact step ``x(k+1)`` of the 3-axis double integrator; ``x`` (6,), ``a`` (3,)."""
    p, v = x[:3], x[3:]
    return jnp.concatenate([p + dt * v + 0.5 * dt * dt * a, v + dt * a])


@dataclasses.dataclass(frozen=True)
class DoubleIntegrator(Plant):
    """The exact discrete double integrator (paper eq. 4–7): the MPC's own model, state ``[p, v]``."""

    def init(self, start: Array, gains: Any, sim: Any) -> Array:
        return jnp.concatenate([start, jnp.zeros(3, start.dtype)])

    def kinematics(self, state: Array) -> Array:
        return state

    def step(self, state: Array, accel: Array, disturbance: Array, gains: Any, sim: Any) -> tuple[Array, dict]:
        return step(state, accel + disturbance, sim.episode.dt), {}

    def linear_model(self, dt: float, dtype: Any) -> tuple[Array, Array]:
        return discrete_matrices(dt, 1, dtype)


register_plant("double_integrator", DoubleIntegrator())

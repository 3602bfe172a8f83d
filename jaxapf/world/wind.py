r"""Disturbances: what acts on the plant besides the command, as registered components.

A :class:`Disturbance` yields, every control step, an acceleration [m/s²] in the world frame that
the plant adds to what its command realises (held over the step), with a state it carries through
the episode. ``none`` (:class:`Calm`, the default) is zero; ``wind`` (:class:`Wind`) is a constant
wind with Ornstein-Uhlenbeck gusts, every parameter a traced gain.

Wind pushes through a linear drag: the acceleration is ``c_w (w̄ + g(t))``, the wind part of the
drag ``c_w (w - v)`` on a vehicle moving at ``v`` in air moving at ``w``. The vehicle's own part
``-c_w v`` belongs to the plant, and the paper's double integrator leaves it out; so does every
plant here, so that a calm world is today's. The gusts ``g`` are three independent stationary OU
processes, ``dg = -g/τ dt + σ sqrt(2/τ) dW``, with ``σ = σ_g`` (``gust_sigma``) on x and y and
``σ_z = r_z σ_g`` on z (``gust_vertical`` = r_z, default 1: isotropic, as before; near the ground
vertical gusts are weaker than horizontal ones), sampled exactly at the control steps:

.. math::  g_{k+1} = e^{-Δt/τ} g_k + σ \sqrt{1 - e^{-2Δt/τ}}\, ξ_k,\qquad g_0 \sim N(0, \mathrm{diag}(σ^2))

(σ per axis) so ``E[g] = 0``, ``Var g = σ²`` per axis and ``corr(g_k, g_{k+l}) = e^{-l Δt/τ}`` at every step. The draws
``ξ_k`` come from the field's key (:func:`~jaxapf.datatypes.episode_key`), independent of the method
and gains.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar

import jax
import jax.numpy as jnp
from jax import Array

from ..datatypes import episode_key
from ..gains import GainSpec
from ..registry import Registry
from ..stage import DECLARE, Stage

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..datatypes import Scenario
    from ..gains import Gains

__all__ = ["Disturbance", "Calm", "Wind", "DISTURBANCES", "register_disturbance"]


class Disturbance(Stage, abc.ABC):
    """An acceleration acting on the plant (a :class:`~jaxapf.stage.Stage`: gains, ``init``)."""

    @abc.abstractmethod
    def __call__(self, state: Any, k: Array, scenario: "Scenario", gains: "Gains",
                 sim: "SimConfig") -> tuple[Array, Any]:
        """``(acceleration (3,) [m/s²] in the world frame held over control step k, next state)``."""


@dataclasses.dataclass(frozen=True)
class Calm(Disturbance):
    """No disturbance (the paper's world)."""

    def __call__(self, state: Any, k: Array, scenario: "Scenario", gains: Any, sim: Any) -> tuple[Array, Any]:
        return jnp.zeros_like(scenario.start), state


@dataclasses.dataclass(frozen=True)
class Wind(Disturbance):
    """A constant horizontal wind with Ornstein-Uhlenbeck gusts on every axis, pushing through a linear drag."""

    gains: ClassVar[tuple[GainSpec, ...]] = (
        GainSpec("wind_speed", 0.0, low=0.0, unit="m/s", symbol="w̄", tunable=False,
                 doc="speed of the constant horizontal wind"),
        GainSpec("wind_heading", 0.0, unit="deg", symbol="ψ_w", tunable=False,
                 doc="direction the wind blows toward, from +x toward +y"),
        GainSpec("gust_sigma", 0.0, low=0.0, unit="m/s", symbol="σ_g", tunable=False,
                 doc="standard deviation of the gusts on each axis"),
        GainSpec("gust_vertical", 1.0, low=0.0, symbol="σ_z/σ_g", tunable=False,
                 doc="standard deviation of the vertical gusts as a multiple of gust_sigma (1: isotropic)"),
        GainSpec("gust_tau", 2.0, low=0.0, low_open=True, unit="s", symbol="τ_g", tunable=False,
                 doc="correlation time of the gusts"),
        GainSpec("wind_drag", 0.3, low=0.0, unit="1/s", symbol="c_w", tunable=False,
                 doc="linear drag per unit mass through which wind pushes (5 m/s: 1.5 m/s²)"),
    )

    def _draw(self, scenario: "Scenario", k: Array) -> Array:
        return jax.random.normal(episode_key(scenario, "wind", k), (3,), scenario.start.dtype)

    @staticmethod
    def _sigma(gains: "Gains") -> Array:
        """σ per axis: ``gust_sigma`` on x and y, ``gust_vertical · gust_sigma`` on z."""
        return gains.gust_sigma * jnp.stack([jnp.ones_like(gains.gust_vertical), jnp.ones_like(gains.gust_vertical),
                                             gains.gust_vertical])

    def init(self, scenario: "Scenario", gains: "Gains", sim: "SimConfig") -> Array:
        return self._sigma(gains) * self._draw(scenario, -1)  # g_0 from the stationary law

    def __call__(self, state: Array, k: Array, scenario: "Scenario", gains: "Gains",
                 sim: "SimConfig") -> tuple[Array, Array]:
        heading = jnp.deg2rad(gains.wind_heading)
        mean = gains.wind_speed * jnp.stack([jnp.cos(heading), jnp.sin(heading), jnp.zeros_like(heading)])
        decay = jnp.exp(-sim.episode.dt / gains.gust_tau)
        gust = decay * state + self._sigma(gains) * jnp.sqrt(1.0 - decay * decay) * self._draw(scenario, k)
        return (gains.wind_drag * (mean + state)).astype(scenario.start.dtype), gust


#: Registered disturbances: the values of ``disturbance`` (default ``none``).
DISTURBANCES: Registry[Disturbance] = Registry("disturbance", on_register=DECLARE,
                                                   role="what acts on the plant besides the command")


def register_disturbance(name: str, disturbance: Disturbance, *, replace: bool = False) -> Disturbance:
    """Register ``disturbance`` as ``disturbance = name`` and declare its gains."""
    return DISTURBANCES.register(name, disturbance, replace=replace)


register_disturbance("none", Calm())
register_disturbance("wind", Wind())

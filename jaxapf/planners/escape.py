"""Stall escape: a planner with state that steers a stalled UAV toward a virtual goal to the side.

:class:`StallEscape` wraps any planner (``init``/``reference``, a pair of pure functions): after ``t_detect``
seconds slow and away from the goal, the wrapped planner flies for ``t_escape`` seconds toward a virtual goal
``d_escape`` metres to the side, the first side drawn from the field's key (purpose ``"escape"``), later ones
alternating. Every quantity is a ``jnp.where`` of the state, so it jit-compiles, vmaps and differentiates.
Registered planners: ``basic_escape`` and ``direction_velocity_escape`` (the paper's weight with the escape:
a variant). The rule and its defaults: docs/spec.md, "stall escape".
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ..datatypes import episode_key
from ..gains import GainSpec
from .apf import APF
from .base import Planner, register_planner
from .weights import Basic, DirectionVelocity

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..datatypes import ObstacleColumns, Scenario
    from ..gains import Gains

__all__ = ["T_DETECT", "T_ESCAPE", "D_ESCAPE", "EscapeState", "StallEscape"]

T_DETECT = GainSpec("t_detect", 2.0, low=0.0, low_open=True, unit="s",
                    doc="stall escape: seconds of low speed far from the goal before an escape starts")
T_ESCAPE = GainSpec("t_escape", 3.0, low=0.0, low_open=True, unit="s",
                    doc="stall escape: seconds the virtual goal replaces the goal")
D_ESCAPE = GainSpec("d_escape", 4.0, low=0.0, low_open=True, unit="m",
                    doc="stall escape: distance of the virtual goal to the side of the UAV")


class EscapeState(NamedTuple):
    """What :class:`StallEscape` carries: the wrapped planner's state, seconds slow so far, seconds
    of escape left, the virtual goal (3,), the number of escapes started and the first escape's
    side (+1 left of the goal direction, -1 right)."""

    inner: Any
    slow: Array
    left: Array
    virtual_goal: Array
    escapes: Array
    first_side: Array


@dataclasses.dataclass(frozen=True)
class StallEscape(Planner):
    """A planner whose stalls far from the goal start escapes toward a virtual goal to the side
    (module docstring)."""

    inner: Planner
    description: str = ""
    color: str | None = None
    linestyle: str | None = None

    @property
    def gains(self) -> tuple[GainSpec, ...]:
        return tuple({g.name: g for g in (*self.inner.gains, T_DETECT, T_ESCAPE, D_ESCAPE)}.values())

    @property
    def reads(self) -> tuple[str, ...]:
        return self.inner.reads

    def init(self, scenario: "Scenario", gains: "Gains", sim: "SimConfig", horizon: int) -> EscapeState:
        zero = jnp.zeros((), scenario.start.dtype)
        left_first = jax.random.bernoulli(episode_key(scenario, "escape"))
        return EscapeState(self.inner.init(scenario, gains, sim, horizon), zero, zero, scenario.goal,
                           jnp.zeros((), jnp.int32), jnp.where(left_first, 1.0, -1.0).astype(zero.dtype))

    def reference(self, state: EscapeState, x: Array, t: Array, goal: Array, obstacles: "ObstacleColumns",
                  gains: "Gains", sim: "SimConfig", horizon: int) -> tuple[Array, EscapeState]:
        dt = sim.episode.dt
        p, v = x[:3], x[3:]
        far = jnp.sum((p - goal) ** 2) > sim.episode.r_goal ** 2
        slow_now = (jnp.sum(v * v) < sim.metrics.v_stall ** 2) & far & (state.left <= 0.0)
        slow = jnp.where(slow_now, state.slow + dt, 0.0)
        start = slow >= gains.t_detect
        # the virtual goal: d_escape to the first side (even escapes) or the other (odd) of the goal direction
        heading = jnp.stack([goal[0] - p[0], goal[1] - p[1]])
        length = jnp.sqrt(jnp.sum(heading * heading))
        heading = jnp.where(length > 1e-9, heading / jnp.where(length > 1e-9, length, 1.0),
                            jnp.asarray([1.0, 0.0], x.dtype))
        side = jnp.where(state.escapes % 2 == 0, 1.0, -1.0).astype(x.dtype) * state.first_side
        lateral = side * jnp.stack([-heading[1], heading[0], jnp.zeros((), x.dtype)])
        virtual_goal = jnp.where(start, p + gains.d_escape * lateral, state.virtual_goal)
        left = jnp.where(start, gains.t_escape, jnp.maximum(state.left - dt, 0.0))
        target = jnp.where(left > 0.0, virtual_goal, goal)
        ref, inner = self.inner.reference(state.inner, x, t, target, obstacles, gains, sim, horizon)
        return ref, EscapeState(inner, jnp.where(start, 0.0, slow), left, virtual_goal,
                                state.escapes + start.astype(jnp.int32), state.first_side)


register_planner("basic_escape", StallEscape(APF(Basic()), color="tab:olive", linestyle="--",
                                             description="basic potential field with stall escape: after t_detect "
                                                         "s slow far from the goal, a virtual goal d_escape to the "
                                                         "side for t_escape s, the first side at random from "
                                                         "the field's key, then alternating"))
register_planner("direction_velocity_escape",
                 StallEscape(APF(DirectionVelocity()), color="tab:gray", linestyle="--",
                             description="the paper's weight (eq. 19) with the stall escape of basic_escape: a "
                                         "variant, so every gain of planner, MPC, filter and escape is tunable"))

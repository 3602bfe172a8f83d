"""The planner protocol and its registry.

A planner turns the UAV's state and what it knows of the obstacles into the MPC's reference
trajectory, ``N + 1`` states for ``x(k..k+N)`` (paper section 2.2), every control step. It is a pair
of pure functions in the spirit of optax's ``init``/``update``: :meth:`Planner.init` makes the
state it carries through an episode (``()`` for a memoryless planner), :meth:`Planner.reference`
maps ``(state, observation)`` to ``(reference, new state)``, and :meth:`Planner.diagnostics` reads
the step's diagnostics (``traj.extras``, e.g. ``vo_infeasible``) from that new state. Both are traced under ``jit``,
``vmap`` and ``grad``; the planner object itself is static (a frozen dataclass).

A planner that plans accelerations itself (MPPI, the keep-out MPC) also answers :meth:`Planner.command`:
the closed loop then applies its plan's first acceleration and no MPC tracks its reference, as their
authors fly them.

Every planner declares the gains it reads (:attr:`Planner.gains`, traced) and the static
:class:`~jaxapf.config.PlannerConfig` fields it reads (:attr:`Planner.reads`): settings that differ
only elsewhere fly the same episodes, which reports use to pair and label settings.

The paper's three methods are potential-field planners (:class:`~jaxapf.planners.apf.APF`); any
planner registered with :func:`register_planner` becomes a value of ``method`` in sweep specs, the
CLI and ``jaxapf tune`` (``docs/extending.md``).
"""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp
from jax import Array

from ..gains import GainSpec
from ..registry import Registry
from ..stage import DECLARE

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..datatypes import ObstacleColumns, Scenario
    from ..gains import Gains

__all__ = ["Planner", "PLANNERS", "register_planner", "reference_states", "shifted"]


class Planner(abc.ABC):
    """A reference generator for the MPC, or a planner commanding its own accelerations (module docstring).

    Attributes:
      color, linestyle: how figures draw its runs (matplotlib colour and line style; ``None``:
        from a palette).
      metrics: the metrics of what only it records (registered with it).
      concurrent_cpu_devices: whether its program may run on several CPU devices at once (``jaxapf
        sweep --devices``); where not, :class:`~jaxapf.engine.devices.DeviceBatch` runs the devices'
        blocks one after another (the same numbers, no concurrency).
    """

    color: str | None = None
    linestyle: str | None = None
    metrics: tuple = ()
    concurrent_cpu_devices: bool = True

    @property
    def description(self) -> str:
        """One line about the planner (default: its class docstring's first line)."""
        doc = (type(self).__doc__ or "").strip()
        return doc.splitlines()[0] if doc else ""

    @property
    @abc.abstractmethod
    def gains(self) -> tuple[GainSpec, ...]:
        """The traced gains the planner reads."""

    @property
    def reads(self) -> tuple[str, ...]:
        """The :class:`~jaxapf.config.PlannerConfig` fields (besides ``method``) the planner reads."""
        return ()

    def init(self, scenario: "Scenario", gains: "Gains", sim: "SimConfig", horizon: int) -> Any:
        """The planner's state at the start of an episode (default: none); it keeps its shapes
        through the episode (``horizon``: the MPC's N, for states shaped like a reference)."""
        return ()

    @abc.abstractmethod
    def reference(self, state: Any, x: Array, t: Array, goal: Array, obstacles: "ObstacleColumns",
                  gains: "Gains", sim: "SimConfig", horizon: int) -> tuple[Array, Any]:
        """The MPC reference (horizon+1, 6) for ``x(k..k+N)`` from the state ``x = [p, v]`` (6,) at
        time ``t`` and the obstacles (component-first), and the planner's next state."""

    @property
    def flies_own_plan(self) -> bool:
        """Whether the planner commands the accelerations itself (it overrides :meth:`command`)."""
        return type(self).command is not Planner.command

    def command(self, state: Any) -> Array | None:
        """The acceleration (3,) the planner commands this step, read from the state :meth:`reference` just
        returned; ``None`` (default, decided when traced): the MPC tracks the reference instead."""
        return None

    def diagnostics(self, state: Any) -> dict[str, Array]:
        """Per-step diagnostics the closed loop records (``traj.extras``), read from the state
        :meth:`reference` just returned (default: none), as a safety filter returns its own."""
        return {}


def reference_states(x: Array, points: Array, velocities: Array, sim: "SimConfig") -> Array:
    """The MPC reference (N + 1, 6) from the state ``x = [p, v]`` and a planner's ``N`` points
    ``p_1..p_N`` with their velocities: ``(p_i, 0)``, the paper's zero velocity reference, or with
    ``PlannerConfig.reference_velocity`` ``(p_i, v_i)``; ``i = 0`` is ``x`` itself."""
    positions = jnp.concatenate([x[None, :3], points], axis=0)
    if sim.planner.reference_velocity:
        velocities = jnp.concatenate([x[None, 3:], velocities], axis=0)
    else:
        velocities = jnp.zeros_like(positions)
    return jnp.concatenate([positions, velocities], axis=1)


def shifted(plan: Array) -> Array:
    """A plan (N, ...) one step on: its first entry flown, the last repeated (the warm start of a planner
    that plans its own accelerations)."""
    return jnp.concatenate([plan[1:], plan[-1:]], axis=0)


def _describe(planner: Planner) -> str:
    gains = ", ".join(g.name for g in planner.gains)
    return f"{planner.description} (gains: {gains})" if gains else planner.description


#: Registered planners: the values of ``method``.
PLANNERS: Registry[Planner] = Registry("planner", describe=_describe, on_register=DECLARE,
                                       role="what turns the UAV's state and the obstacles into the MPC's reference")


def register_planner(name: str, planner: Planner, *, replace: bool = False) -> Planner:
    """Register ``planner`` as ``method = name`` (its gains are declared)."""
    return PLANNERS.register(name, planner, replace=replace)

"""An out-of-package plugin for tests/test_extending.py: one of each extension point, each a few lines.

- weight ``sideways``: ω = 1 + β (s_y/|s|)² weighs obstacles to the side of the UAV more, with a
  declared gain β; registered with a force term ``drift`` (a constant push along +y, gain ``drift``)
  as the planner ``sideways_drift``;
- safety filter ``damped``: a ← clip(a - c_d v, ±a_max), gain ``c_d``, with a per-step diagnostic;
- scenario family ``pillar``: one cylinder on the start–goal line, kinds ``thin`` and ``thick``;
- metric ``mean_speed``: the UAV's mean speed over the episode's valid samples.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax.numpy as jnp

import jaxapf
from jaxapf.planners.sight import norm
from jaxapf.scenarios import FamilyParams, register_family
from jaxapf.scenarios.base import number, span
from jaxapf.scenarios.layout import Layout

BETA = jaxapf.GainSpec("beta", 0.5, low=0.0, doc="side weight β of the sideways weight")
DRIFT = jaxapf.GainSpec("drift", 0.2, low=0.0, doc="constant push along +y", unit="m/s²")
C_D = jaxapf.GainSpec("c_d", 0.3, low=0.0, high=1.0, doc="damping of the damped filter", unit="1/s")


@dataclasses.dataclass(frozen=True)
class Sideways(jaxapf.Weight):
    """ω = 1 + β (s_y/|s|)²: obstacles to the side weigh more."""

    gains: ClassVar = (BETA,)

    def __call__(self, sight, gains, *, convention, eps_v):
        return 1.0 + gains.beta * (sight.s[1] / norm(sight.s)) ** 2


@dataclasses.dataclass(frozen=True)
class Drift(jaxapf.ForceTerm):
    """A constant push along +y."""

    gains: ClassVar = (DRIFT,)

    def __call__(self, p, v, t, goal, obstacles, gains, sim):
        return jnp.stack([jnp.zeros_like(gains.drift), gains.drift, jnp.zeros_like(gains.drift)])


@dataclasses.dataclass(frozen=True)
class Damped(jaxapf.SafetyFilter):
    """a ← clip(a - c_d v, ±a_max)."""

    gains: ClassVar = (C_D,)

    def __call__(self, state, accel, x, t, obstacles, gains, sim):
        damped = jnp.clip(accel - gains.c_d * x[3:], -sim.vehicle.a_max, sim.vehicle.a_max)
        return damped, state, {"damping": jnp.linalg.norm(damped - accel)}


@dataclasses.dataclass(frozen=True)
class PillarParams(FamilyParams):
    """``pillar``: one cylinder on the start–goal line at ``along`` of the run; thin or thick."""

    family = "pillar"
    CHECKS = FamilyParams.CHECKS | {"along": span(0.0, 1.0), "thin": span(0.0, lo_open=True),
                                    "thick": number(0.0, lo_open=True)}

    max_obstacles: int = 1
    distance: tuple[float, float] = (8.0, 10.0)
    along: tuple[float, float] = (0.4, 0.6)
    thin: tuple[float, float] = (0.3, 0.5)
    thick: float = 1.2


def _pillar(d: Any, p: PillarParams, length: Any) -> tuple[Layout, Any]:
    x = d.uniform(p.along) * length
    thick = d.uniform((0.0, 1.0)) < 0.5
    radius = jnp.where(thick, p.thick, d.uniform(p.thin))
    xy = jnp.stack([x, jnp.zeros_like(x)])[None]
    return Layout(xy, jnp.zeros_like(xy), radius[None], jnp.ones((1,), bool)), thick.astype(jnp.int32)


def _mean_speed(ctx: jaxapf.EpisodeContext):
    speed = jnp.linalg.norm(ctx.traj.velocity, axis=-1)
    return jnp.sum(jnp.where(ctx.sample_valid, speed, 0.0)) / jnp.sum(ctx.sample_valid)


jaxapf.register_planner("sideways", jaxapf.APF(Sideways(), description="test plugin: obstacles to the side weigh more"))
jaxapf.register_planner("sideways_drift", jaxapf.APF(Sideways(), terms=(Drift(),), description="test plugin"))
jaxapf.register_filter("damped", Damped())
register_family(PillarParams, _pillar, ("thin", "thick"), description="test plugin: one pillar on the line")
jaxapf.register_metric(jaxapf.Metric("mean_speed", _mean_speed, unit="m/s", higher_is_better=True, report=True,
                                     doc="mean speed over the episode"))

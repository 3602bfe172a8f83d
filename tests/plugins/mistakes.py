"""Plugin components with the mistakes a newcomer makes (tests/test_extending.py): a weight ω of the wrong
shape, a weight reading a gain nobody declared, a planner whose reference has the wrong shape, a filter that
lets a horizontal acceleration through in place of the whole, a weight that is not a number near an obstacle, a
weight whose own code fails while it is traced."""

import dataclasses
from typing import ClassVar

import jax.numpy as jnp

import jaxapf

K_C = jaxapf.GainSpec("k_c", 1.0, low=0.0, doc="the mistakes' gain")


@dataclasses.dataclass(frozen=True)
class Wide(jaxapf.Weight):
    """ω of shape (3, M) where one per obstacle, (M,), is read."""

    gains: ClassVar = (K_C,)
    uses_convention: ClassVar = False

    def __call__(self, sight, gains, *, convention, eps_v):
        return jnp.ones((3,) + jnp.shape(sight.s[0]))


@dataclasses.dataclass(frozen=True)
class Misspelled(Wide):
    """Reads ``k_cc``, declared by no one (``k_c`` meant)."""

    def __call__(self, sight, gains, *, convention, eps_v):
        return 1.0 + gains.k_cc * jnp.ones(jnp.shape(sight.s[0]))


@dataclasses.dataclass(frozen=True)
class NotANumber(Wide):
    """ω = NaN: harmless while every obstacle is beyond the influence distance d_s, poison once one is within."""

    def __call__(self, sight, gains, *, convention, eps_v):
        return jnp.full(jnp.shape(sight.s[0]), jnp.nan)


@dataclasses.dataclass(frozen=True)
class Broken(Wide):
    """Reads a field the sight has not: an AttributeError of the plugin's own, raised while the loop is traced."""

    def __call__(self, sight, gains, *, convention, eps_v):
        return 1.0 + sight.closing_speed  # BROKEN LINE


@dataclasses.dataclass(frozen=True)
class Short(jaxapf.Planner):
    """The basic planner's reference without its last point: (N, 6) where (N + 1, 6) is read."""

    inner: jaxapf.Planner

    @property
    def gains(self):
        return self.inner.gains

    @property
    def reads(self):
        return self.inner.reads

    def init(self, scenario, gains, sim, horizon):
        return self.inner.init(scenario, gains, sim, horizon)

    def reference(self, state, x, t, goal, obstacles, gains, sim, horizon):
        x_ref, state = self.inner.reference(state, x, t, goal, obstacles, gains, sim, horizon)
        return x_ref[:-1], state


@dataclasses.dataclass(frozen=True)
class Flat(jaxapf.SafetyFilter):
    """Returns the horizontal acceleration, (2,), where the loop reads (3,)."""

    def __call__(self, state, accel, x, t, obstacles, gains, sim):
        return accel[:2], state, {}


jaxapf.register_planner("wide", jaxapf.APF(Wide()))
jaxapf.register_filter("flat", Flat())
jaxapf.register_planner("misspelled", jaxapf.APF(Misspelled()))
jaxapf.register_planner("short", Short(jaxapf.PLANNERS["basic"]))
jaxapf.register_planner("not_a_number", jaxapf.APF(NotANumber()))
jaxapf.register_planner("broken", jaxapf.APF(Broken()))

r"""Ge–Cui repulsion: the repulsion fades as the UAV nears the goal, so the goal stays the minimum.

With the classical potential an obstacle within ``d_s`` of the goal keeps repelling at the goal
itself, so the total potential's minimum moves off the goal and the UAV settles short of it
(goals non-reachable with obstacles nearby, GNRON). Ge and Cui ("New potential functions for
mobile robot path planning", IEEE Trans. Robotics and Automation 16(5), 2000) multiply the
repulsive potential by the distance to the goal raised to a power, :math:`\rho_g^n` with
:math:`\rho_g = |p - g|`, so that it and its force vanish at the goal. jaxapf uses the bounded form

.. math::
   \omega = \Big(\frac{\rho_g^2}{\rho_g^2 + d_s^2}\Big)^{n/2},
   \qquad U^*_{rep} = \omega\, U_{rep}(d)

which is Ge and Cui's factor up to a constant near the goal (:math:`\omega \approx (\rho_g/d_s)^n`
for :math:`\rho_g \ll d_s`) and tends to 1 far from it: the planner is the basic potential field
(same strength, ω = 1) wherever the goal is far, and differs from it only where the goal is
within a few ``d_s``. The unbounded :math:`\rho_g^n` would multiply the repulsion by
:math:`\rho_g^n` everywhere (hundreds at tens of metres with ``n = 2``), a different planner
altogether. As for every weight, the force is :math:`-\nabla_p(\omega U_{rep})` by ``jax.grad``,
so it has Ge and Cui's second component (pointing at the goal, from :math:`U_{rep}\nabla\omega`).
``n = 0`` gives the basic planner's episodes (to float rounding: the program differs).

Registered planner: ``ge_cui_bounded`` (gains ``n_g`` and the basic potential's): a *variant* of Ge
and Cui's planner, and named so, because ω is not their :math:`\rho_g^n`.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax.numpy as jnp
from jax import Array

from ..gains import GainSpec
from .apf import APF
from .base import register_planner
from .sight import Sight
from .weights import Weight

__all__ = ["N_G", "GoalDistance"]

N_G = GainSpec("n_g", 2.0, low=0.0, symbol="n",
               doc="Ge–Cui goal exponent n: the repulsion is scaled by (ρ_g²/(ρ_g² + d_s²))^(n/2), ρ_g = |p - g|")


@dataclasses.dataclass(frozen=True)
class GoalDistance(Weight):
    """ω = (ρ_g²/(ρ_g² + d_s²))^(n/2), ρ_g = |p - g|: Ge–Cui's goal-distance factor, bounded (module
    docstring)."""

    gains: ClassVar[tuple[GainSpec, ...]] = (N_G,)

    def __call__(self, sight: Sight, gains: Any, *, convention: str, eps_v: float) -> Array:
        if sight.goal is None:  # a single obstacle's potential, no goal known: the classical one
            return jnp.ones((), jnp.result_type(sight.v))
        to_goal = sight.p - sight.goal
        rho2 = jnp.sum(to_goal * to_goal)
        # (ρ²/(ρ² + d_s²))^(n/2) as exp(n/2 · log(…)), with log(0) guarded: 0 at the goal for n > 0
        ratio = rho2 / (rho2 + gains.d_s * gains.d_s)
        safe = jnp.where(ratio > 0.0, ratio, 1.0)
        return jnp.where(ratio > 0.0, safe ** (0.5 * gains.n_g), jnp.where(gains.n_g > 0.0, 0.0, 1.0))

    def bounds(self, gains: Any) -> tuple[Array, Array]:
        return jnp.zeros_like(gains.n_g), jnp.ones_like(gains.n_g)

    def reference(self, gains: Any, *, convention: str = "intent", eps_v: float = 1e-3) -> Array:
        """Far from the goal, ω → 1 (the basic potential's strength)."""
        return jnp.ones((), jnp.result_type(float))


register_planner("ge_cui_bounded", APF(GoalDistance(), color="tab:brown", linestyle="--",
                                     description="bounded variant of Ge–Cui: the basic repulsion scaled by "
                                                 "(ρ_g²/(ρ_g² + d_s²))^(n/2), vanishing at the goal "
                                                 "(after Ge & Cui 2000)"))

r"""A vortex (tangential) force: the repulsion turned by 90° in the horizontal plane (De Luca and Oriolo, ICRA 1994).

A potential field stalls in front of an obstacle on the line to the goal, where repulsion and
attraction are anti-parallel; the vortex term :math:`T = k_v \sum_o σ_o R(-90°) F_{o,xy}` turns each
obstacle's basic repulsion toward the goal's side of the line of sight as seen from the obstacle (so a
moving obstacle is passed on the side its relative motion already takes). It has no z component and is
added to the flow's force at every prediction point (:class:`~jaxapf.planners.apf.ForceTerm`). Registered
planner: ``vortex`` = ``APF(Basic(), terms=(Vortex(),))``. The side rule and why the world-frame goal side
is wrong for an obstacle from behind: docs/spec.md, "the vortex planner".
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, ClassVar

import jax
import jax.numpy as jnp
from jax import Array

from ..datatypes import ObstacleColumns
from ..gains import GainSpec
from .apf import APF, ForceTerm
from .base import register_planner
from .potentials import repulsive_potential
from .sight import line_of_sight, norm
from .weights import Basic

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..gains import Gains

__all__ = ["K_V", "Vortex", "vortex_side"]

K_V = GainSpec("k_v", 1.0, low=0.0, symbol="k_v",
               doc="vortex gain: the tangential force is k_v times the repulsion's horizontal magnitude")


def vortex_side(s_x: Array, s_y: Array, w_x: Array, w_y: Array) -> Array:
    """σ per obstacle: +1 where the preferred relative velocity ``(w_x, w_y)`` points left of (or
    along) the horizontal line of sight ``(s_x, s_y)``, -1 where it points right (module docstring)."""
    cross = s_x * w_y - s_y * w_x
    return jnp.where(cross >= 0.0, 1.0, -1.0).astype(s_x.dtype)


@dataclasses.dataclass(frozen=True)
class Vortex(ForceTerm):
    """The repulsion turned by 90° toward the side the preferred relative motion passes (module docstring)."""

    gains: ClassVar[tuple[GainSpec, ...]] = (K_V,)

    def __call__(self, p: Array, v: Array, t: Array, goal: Array, obstacles: ObstacleColumns, gains: "Gains",
                 sim: "SimConfig") -> Array:
        centres = obstacles.position + obstacles.velocity * t
        s = line_of_sight(p, centres, obstacles.cylinder)
        dist = norm(s)
        clearance = dist - obstacles.radius - sim.vehicle.r_uav
        # dU/dd of every obstacle at once (U_rep is elementwise in d); F_o = -dU/dd ∇d = (dU/dd) ŝ
        slope = jax.grad(lambda d: jnp.sum(repulsive_potential(d, gains.k_rep, gains.d_s, sim.planner.d_min)))(
            clearance)
        magnitude = jnp.where(obstacles.valid, -slope, 0.0) / dist  # |F_o| / |s|, >= 0
        to_goal = goal - p
        preferred = sim.vehicle.v_max * to_goal / norm(to_goal)
        w = preferred[:2, None] - obstacles.velocity[:2]  # the preferred velocity seen from each obstacle
        side = vortex_side(s[0], s[1], w[0], w[1])
        # σ R(-90°) F_xy = σ |F| R(+90°) ŝ_xy = σ |F| (-ŝ_y, ŝ_x)
        fx = jnp.sum(side * magnitude * -s[1])
        fy = jnp.sum(side * magnitude * s[0])
        return gains.k_v * jnp.stack([fx, fy, jnp.zeros_like(fx)])


register_planner("vortex", APF(Basic(), terms=(Vortex(),), color="tab:green", linestyle="-.",
                               description="basic potential field plus a vortex: the repulsion turned 90° toward the "
                                           "side the preferred relative motion passes each obstacle (De Luca & Oriolo "
                                           "1994)"))

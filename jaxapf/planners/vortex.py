r"""A vortex (tangential) force: the repulsion turned by 90° in the horizontal plane.

A potential field cannot steer around an obstacle that sits on the line to the goal: there the
repulsion is anti-parallel to the attraction and the flow stalls (the GNRON trap). A vortex field
(De Luca and Oriolo, "Local incremental planning for nonholonomic mobile robots", ICRA 1994)
adds, near each obstacle, a force tangential to it. Here, per obstacle ``o`` with horizontal line
of sight :math:`s_o = P(p_o - p)_{xy}` and basic repulsive force
:math:`F_o = -\nabla_p U_{rep}(d_o)` (paper eq. 13, zero beyond ``d_s``):

.. math::
   T_{vortex} = k_v \sum_o \sigma_o\, R(-90°)\, F_{o,xy}, \qquad
   \sigma_o = \begin{cases} +1 & (s_o \times w_o)_z \ge 0 \\ -1 & \text{otherwise} \end{cases},
   \qquad w_o = v_{max} \frac{g - p}{|g - p|} - v_o

so each term has the repulsion's magnitude times ``k_v``, is perpendicular to it, and turns the
UAV toward the side of the line of sight on which its preferred relative motion ``w_o`` passes
(``σ = +1``: ``w_o`` points left of ``s_o``, the term points along :math:`R(+90°)\hat s_o`,
counter-clockwise around the obstacle). ``w_o`` is the velocity the UAV wants (``v_max`` toward
the goal, the flow's saturated speed) seen from the obstacle, so **the side rule** is the goal's
side of the line of sight in the obstacle's frame: for a static obstacle it is exactly the goal's
side (De Luca and Oriolo's rule), for a moving one the side on which the relative motion already
passes, as the dynamic-obstacle vortex fields choose it (the rotation follows the relative
velocity). Taking the goal's side in the world frame instead sends the UAV *into* an obstacle
that comes from behind: its line of sight points away from the goal, so the goal's side of it is
the obstacle's own lateral side. The side is a function of the current geometry only (no
memory) and does not depend on the UAV's own velocity, so it does not chatter as the UAV turns;
``w_o`` exactly on the line counts as left. The term has no z component, so it acts in the plane
the paper's scenarios fly in; it is added to the flow's force at every prediction point
(:class:`~jaxapf.planners.apf.ForceTerm`), obstacles extrapolated like the repulsion's.

Registered planner: ``vortex`` = ``APF(Basic(), terms=(Vortex(),))`` (gains ``k_v`` and the basic
potential's).
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

r"""APF reference generation: N prediction points by a saturated gradient flow (SPEC 4).

Starting from the current ``(p_0, v_0) = (p, v)`` at time ``t``:

.. math::
   F_i = -\nabla_p\Big[U_{att}(p_i) + \sum_o U^*_{rep}(p_i, v_i, p_o(t_i), v_o)\Big], \quad
   u_i = \mathrm{sat}_{v_{max}}(\eta F_i), \quad
   p_{i+1} = p_i + \Delta t\, u_i, \quad v_{i+1} = u_i

with obstacles extrapolated at constant velocity, ``p_o(t_i) = p_o + v_o (t + i Δt)``, which makes
the scheme predictive; ``sat`` clips the norm. The MPC reference is ``(P_pred, 0)`` (the paper's zero
velocity reference) or, with ``SimConfig.reference_velocity``, ``(P_pred, [v, u_0, …, u_{N-1}])``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from .config import Gains, SimConfig
from .obstacles import ObstacleColumns, Obstacles, safe_norm
from .potentials import total_force

__all__ = ["saturate", "apf_reference"]


def saturate(u: Array, limit: float) -> Array:
    """Scale ``u`` down to norm ``limit`` if it is longer (direction kept)."""
    return u * jnp.minimum(1.0, limit / safe_norm(u))


def apf_reference(
    x: Array, t: Array, goal: Array, obstacles: Obstacles | ObstacleColumns, gains: Gains, sim: SimConfig,
    horizon: int,
) -> Array:
    """MPC reference states (horizon+1, 6) for ``x(k..k+N)`` from the APF gradient flow.

    ``obstacles`` in either layout; a closed loop passes :class:`ObstacleColumns`, converted once per
    episode (:meth:`Obstacles.columns`), so no control step transposes the field again.
    """
    obstacles = obstacles.columns()

    def flow(carry, i):
        p, v = carry
        force = total_force(
            p, v, t + i * sim.dt, goal, obstacles, gains, method=sim.method, convention=sim.convention,
            r_uav=sim.r_uav, d_min=sim.d_min, eps_v=sim.eps_v, att_cap=sim.att_cap,
        )
        u = saturate(gains.eta * force, sim.v_max)
        return (p + sim.dt * u, u), (p + sim.dt * u, u)

    p0, v0 = x[:3], x[3:]
    _, (points, flows) = jax.lax.scan(flow, (p0, v0), jnp.arange(horizon, dtype=x.dtype))
    positions = jnp.concatenate([p0[None], points], axis=0)
    if sim.reference_velocity:
        velocities = jnp.concatenate([v0[None], flows], axis=0)
    else:
        velocities = jnp.zeros_like(positions)
    return jnp.concatenate([positions, velocities], axis=1)

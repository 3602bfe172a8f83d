r"""Control-barrier-function safety filters for the double integrator: ``cbf`` (the exponential CBF
of Nguyen & Sreenath 2016 / Xiao & Belta 2019, one row ``g_o·a >= b_o`` per obstacle, its rates
``cbf_p1``, ``cbf_p2`` the roots of the characteristic polynomial), ``robust_cbf`` (each row tightened
by the disturbance bound ``cbf_margin``) and ``braking_cbf`` (a stopping-distance barrier that knows
the box, ``cbf_brake``, ``cbf_alpha``). Each replaces the MPC's first acceleration by the nearest one
that keeps every row, solved exactly by :func:`jaxapf.projection.nearest_feasible`; steps where no
acceleration in the box keeps them all are counted (``cbf_infeasible``), as are rows left out that
bind (``cbf_truncated``). The barriers, their guarantees and where they end: docs/spec.md, section 4,
"the CBF safety filter" and "the robust CBFs"."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, Literal

import jax.numpy as jnp
from jax import Array

from ..datatypes.obstacles import TINY
from ..gains import GainSpec
from ..planners.sight import dot, line_of_sight, norm
from ..projection import INFEASIBLE_TOL, nearest_feasible, projection_metrics
from .filters import SafetyFilter, register_filter

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..datatypes import ObstacleColumns
    from ..gains import Gains

__all__ = ["CBF", "CBF_P1", "CBF_P2", "CBF_MARGIN", "CBF_ALPHA", "CBF_BRAKE", "cbf_coefficients", "cbf_constraints",
           "braking_constraints", "INFEASIBLE_TOL"]

CBF_P1 = GainSpec("cbf_p1", 1.0, low=0.0, low_open=True, unit="1/s", symbol="p_1",
                  doc="CBF filter: first root rate, h'' + (p_1 + p_2) h' + p_1 p_2 h >= 0")
CBF_P2 = GainSpec("cbf_p2", 1.0, low=0.0, low_open=True, unit="1/s", symbol="p_2",
                  doc="CBF filter: second root rate, h'' + (p_1 + p_2) h' + p_1 p_2 h >= 0")
CBF_MARGIN = GainSpec("cbf_margin", 0.5, low=0.0, unit="m/s²", symbol="δ", tunable=False,
                      doc="robust CBF filter: the largest unknown acceleration (disturbance, or its estimate's "
                          "error) the condition holds against")
CBF_ALPHA = GainSpec("cbf_alpha", 2.0, low=0.0, low_open=True, unit="1/s", symbol="α",
                     doc="braking CBF filter: rate of its condition, h_b' >= -α h_b")
CBF_BRAKE = GainSpec("cbf_brake", 0.5, low=0.05, high=0.5, unit="", symbol="κ",
                     doc="braking CBF filter: the share of a_max - δ held in reserve for braking to a stop")


def cbf_coefficients(gains: "Gains") -> tuple[Array, Array]:
    """``(k_0, k_1) = (p_1 p_2, p_1 + p_2)``: the condition's coefficients from the two rates, so the
    roots of ``s^2 + k_1 s + k_0`` are ``-p_1`` and ``-p_2``, real and negative."""
    return gains.cbf_p1 * gains.cbf_p2, gains.cbf_p1 + gains.cbf_p2


def cbf_constraints(x: Array, t: Array, obstacles: "ObstacleColumns", gains: "Gains",
                    sim: "SimConfig") -> tuple[Array, Array]:
    """The rows ``g_o`` (M, 3) and bounds ``b_o`` (M,) of ``g_o·a >= b_o`` (module docstring), each
    row scaled to unit length; padded slots get ``g = 0, b = -1`` (always satisfied)."""
    # the line of sight s = P(c_o(t) - p) and the relative velocity P(v_o - v) are -r and -w:
    # h, h' and b read only products of two of them, g = 2r / |2r| = -s / |s|
    s = line_of_sight(x[:3], obstacles.position + obstacles.velocity * t, obstacles.cylinder)
    u = line_of_sight(x[3:], obstacles.velocity, obstacles.cylinder)
    big_r = obstacles.radius + sim.vehicle.r_uav
    h = dot(s, s) - big_r * big_r
    k0, k1 = cbf_coefficients(gains)
    b = -2.0 * dot(u, u) - 2.0 * k1 * dot(s, u) - k0 * h
    length = 2.0 * norm(s)
    g = -2.0 * jnp.stack(s, axis=-1) / length[:, None]
    valid = obstacles.valid
    return jnp.where(valid[:, None], g, 0.0), jnp.where(valid, b / length, -1.0)


def braking_constraints(x: Array, t: Array, obstacles: "ObstacleColumns", gains: "Gains",
                        sim: "SimConfig") -> tuple[Array, Array]:
    """The unit rows ``r̂`` (M, 3) and bounds (M,) of the braking CBF, ``r̂·a >= δ - c - φ'(d) ḋ - α h_b``
    (module docstring); padded slots get ``g = 0, b = -1``."""
    s = line_of_sight(x[:3], obstacles.position + obstacles.velocity * t, obstacles.cylinder)
    u = line_of_sight(x[3:], obstacles.velocity, obstacles.cylinder)
    distance = norm(s)
    d = distance - (obstacles.radius + sim.vehicle.r_uav) - 0.5 * sim.vehicle.a_max * sim.episode.dt ** 2
    rate = dot(s, u) / distance  # ḋ = r̂·w with r̂ = -s/|s|, w = -u
    turning = jnp.maximum(dot(u, u) - rate * rate, 0.0) / distance
    brake = gains.cbf_brake * jnp.maximum(sim.vehicle.a_max - gains.cbf_margin, 0.0)
    lam = 0.5 / sim.episode.dt
    near = lam * lam * d < 2.0 * brake  # d < d* = 2β/λ²: the exponential approach
    root = jnp.sqrt(jnp.maximum(2.0 * brake * d, TINY))
    h = rate + jnp.where(near, lam * d, root)
    slope = jnp.where(near, lam, brake / jnp.where(near, 1.0, root))  # φ'(d)
    b = gains.cbf_margin - turning - slope * rate - gains.cbf_alpha * h
    g = -jnp.stack(s, axis=-1) / distance[:, None]
    valid = obstacles.valid
    return jnp.where(valid[:, None], g, 0.0), jnp.where(valid, b, -1.0)


@dataclasses.dataclass(frozen=True)
class CBF(SafetyFilter):
    """CBF filter: the acceleration in the box nearest the MPC's that keeps each obstacle's barrier
    condition (module docstring): the exponential one, h'' + k1 h' + k0 h >= 0 with k1 = p1 + p2,
    k0 = p1 p2, held against an unknown acceleration of norm δ if ``robust``; or the braking one."""

    barrier: Literal["exponential", "braking"] = "exponential"
    robust: bool = False

    def __post_init__(self) -> None:
        if self.barrier == "braking" and not self.robust:
            raise ValueError("the braking CBF holds its margin δ by construction: CBF(barrier='braking', robust=True)")
    metrics = projection_metrics("cbf", "the CBF filter's constraints", "the acceleration box", "0 without this filter")

    @property
    def summary(self) -> str:
        if self.barrier == "braking":
            return ("Braking CBF: the acceleration nearest the MPC's that keeps, against any push up to cbf_margin, "
                    "enough of the box in reserve to brake to a stop before each obstacle (stays feasible against "
                    "fast obstacles).")
        return ("Robust exponential CBF: the acceleration nearest the MPC's with h'' + k1 h' + k0 h >= 0 per obstacle "
                "against any push up to cbf_margin." if self.robust else
                "Exponential CBF: the acceleration nearest the MPC's with h'' + k1 h' + k0 h >= 0 per obstacle, "
                "k1 = p1 + p2, k0 = p1 p2.")

    @property
    def gains(self) -> tuple[GainSpec, ...]:
        if self.barrier == "braking":
            return CBF_ALPHA, CBF_MARGIN, CBF_BRAKE
        return (CBF_P1, CBF_P2, CBF_MARGIN) if self.robust else (CBF_P1, CBF_P2)

    def __call__(self, state: Any, accel: Array, x: Array, t: Array, obstacles: "ObstacleColumns", gains: "Gains",
                 sim: "SimConfig") -> tuple[Array, Any, dict[str, Array]]:
        if self.barrier == "braking":
            g, b = braking_constraints(x, t, obstacles, gains, sim)
        else:
            g, b = cbf_constraints(x, t, obstacles, gains, sim)
            if self.robust:  # unit rows: the worst unknown acceleration of norm δ takes δ off g·a
                b = jnp.where(obstacles.valid, b + gains.cbf_margin, b)
        applied, worst, exact = nearest_feasible(accel, g, b, sim.vehicle.a_max, "box", sim.planner.projection_rows)
        return applied, state, {"cbf_infeasible": worst > INFEASIBLE_TOL, "cbf_truncated": ~exact}


register_filter("cbf", CBF())
register_filter("robust_cbf", CBF(robust=True))
register_filter("braking_cbf", CBF(barrier="braking", robust=True))

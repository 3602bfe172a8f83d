r"""Control-barrier-function safety filter for the double integrator (``filter = "cbf"``).

For obstacle ``o`` at time ``t`` (centre ``c_o(t) = p_o + v_o t``, constant velocity) let
``r = P(p - c_o(t))`` and ``w = P(v - v_o)`` (``P`` drops z for a cylinder) and ``R = ρ_o + r_uav``.
The barrier is

.. math:: h_o = |r|^2 - R^2, \qquad \dot h_o = 2 r\cdot w, \qquad
          \ddot h_o = 2|w|^2 + 2 r\cdot a

(the obstacle does not accelerate, ``r·P a = r·a``). ``h`` has relative degree two in the
acceleration ``a``, so the filter enforces the exponential (high-order) CBF condition of Nguyen &
Sreenath (2016, "Exponential control barrier functions for enforcing high relative-degree safety-
critical constraints", ACC) / Xiao & Belta (2019, "Control barrier functions for systems with high
relative degree", CDC):

.. math:: \ddot h_o + k_1 \dot h_o + k_0 h_o \ge 0
          \iff g_o\cdot a \ge b_o,\quad g_o = 2r,\quad b_o = -2|w|^2 - 2 k_1\, r\cdot w - k_0 h_o,

one linear constraint per valid obstacle. The gains are two positive rates ``p_1`` (``cbf_p1``) and
``p_2`` (``cbf_p2``), and the filter computes

.. math:: k_1 = p_1 + p_2, \qquad k_0 = p_1 p_2, \qquad s^2 + k_1 s + k_0 = (s + p_1)(s + p_2),

so the characteristic polynomial always has the real negative roots ``-p_1, -p_2``. The
condition reads ``(d/dt + p_1)(d/dt + p_2) h >= 0``; ``ψ_1 = ḣ + p_2 h`` then
satisfies ``ψ̇_1 >= -p_1 ψ_1``, so ``ψ_1(t) >= ψ_1(0) e^{-p_1 t} >= 0`` when ``ψ_1(0) >= 0``, and
``ḣ >= -p_2 h`` keeps ``h(t) >= h(0) e^{-p_2 t} >= 0``: in continuous time, and while the condition
can be met, the safe set is forward invariant from every
start with ``h(0) >= 0`` and ``ḣ(0) + p_2 h(0) >= 0`` (Nguyen & Sreenath's condition, which needs
real negative roots; searching ``k_0, k_1`` independently left it whenever ``k_1^2 < 4 k_0``). The
defaults ``p_1 = p_2 = 1`` are the former ``k_0 = 1, k_1 = 2`` (both roots at -1). The applied
acceleration is

.. math:: a^* = \arg\min_a \tfrac12 |a - a_\mathrm{mpc}|^2 \;\text{s.t.}\; g_o\cdot a \ge b_o\;\forall o,
          \quad |a_i| \le a_\mathrm{max},

solved exactly by :func:`jaxapf.projection.nearest_feasible` (each row of ``G`` scaled to unit
length): in R³ at most three constraints are active, so the solution is the nearest feasible one
of the candidates that every set of up to three active constraints gives -- a fixed amount of work
that vmaps and differentiates. When the constraints and the box cannot all hold, the step is
counted as infeasible (diagnostic ``cbf_infeasible``, metric ``cbf_infeasible_steps``) and the acceleration
in the box with the least largest violation (nearest ``a_mpc`` among those) is applied. Among many
obstacles, ``sim.projection_rows`` solves with that many rows at a time (those that can bind soonest,
then those the answer needs: :func:`~jaxapf.projection.nearest_feasible`); a step whose answer a row
left out still violates by more than the kept rows is counted (``cbf_truncated``, metric
``cbf_truncated_steps``; its largest violation then counts in ``cbf_infeasible`` too when above the
tolerance, though the full problem may have been feasible).

The condition is the continuous-time one, applied with the control held for ``dt``: it guarantees
nothing between samples, which the swept clearance of the metrics measures.

Robust (``robust_cbf``, input-to-state safety against a bounded disturbance): the UAV's acceleration
is ``a + e`` with an unknown ``e``, ``|e| <= δ`` (``cbf_margin``): a wind gust, or the error of a
disturbance estimate the loop already adds (:mod:`jaxapf.control.estimators`). With unit rows the
worst ``e`` lowers ``g_o·(a + e)`` by ``δ``, so the filter enforces ``g_o·a >= b_o + δ``: the
condition then holds for every admissible ``e``, at the price of infeasible steps where the box
cannot absorb ``δ``. That happens where it matters: with the box ``a_max`` fixed, the exponential
condition asks for more than the box holds when an obstacle closes fast (it does so even with
``δ = 0``), so it keeps no guarantee against fast movers.

Braking (``braking_cbf``, robust by construction): a barrier that knows the box. With the distance
``d = |r| - R``, its rate ``ḋ = r̂·w`` and a braking deceleration ``β = κ (a_max - δ)`` held in
reserve (``κ``: ``cbf_brake`` <= 1/2),

.. math:: h_b = \dot d + φ(d),\quad φ(d) = \begin{cases} \sqrt{2 β d} & d \ge d^* \\ λ d & d < d^* \end{cases},
          \qquad \ddot d = r̂·(a + e) + c,\quad c = (|w|^2 - \dot d^2)/|r| \ge 0,

``h_b >= 0`` says the closing speed can still be braked to zero, by ``β`` along ``r̂``, before
contact (the stopping-distance barrier of Ames et al., 2014, "Control barrier function based quadratic
programs with application to adaptive cruise control", CDC; in the obstacle's frame, inertial as it
does not accelerate). Its last ``d^* = 2β/λ^2`` metres are an exponential approach at the rate
``λ = 1/(2Δt)`` the held control can follow (the square root's slope grows without bound at
contact, and a sampled filter chatters there). ``h_b`` has relative degree one; the filter enforces
``ḣ_b >= -α h_b`` (``cbf_alpha``) against every ``|e| <= δ``:

.. math:: r̂·a \ge δ - c - φ'(d)\, \dot d - α h_b .

(``φ`` is continuous but not smooth at ``d^*``, where its slope falls from ``λ`` to ``λ/2``: the
smaller of two barriers.) On the boundary ``h_b = 0`` the right side is ``δ + β - c`` (or
``δ + λ^2 d - c <= δ + 2β``), at most ``a_max`` as ``κ <= 1/2``, ``δ < a_max`` and the box holds
``a_max`` in every direction; inside it is smaller: one obstacle never makes a step infeasible from
the safe set, whatever its speed; several on opposite sides still can (those steps are counted as
above), and an obstacle first met with ``h_b < 0`` (too close for its closing speed) is outside any
guarantee (not counted: study 13 checks its episodes' starts itself). The condition is
continuous-time and the control is held for ``dt``, so ``d`` is measured from ``R + a_max dt²/2``:
a sampling buffer, the distance an acceleration of ``a_max`` covers from rest in one step.
"""

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

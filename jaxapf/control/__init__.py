"""Control: the tracking MPC (paper eq. 8–12) and the safety filters between it and the plant."""

from .cbf import CBF, cbf_coefficients, cbf_constraints
from .filters import FILTERS, Passthrough, SafetyFilter, register_filter
from .mpc import (
                  AxisProblem,
                  augmented_weights,
                  axis_problem,
                  condensed_hessian,
                  condensed_linear,
                  condensed_qp,
                  fista,
                  prediction_matrices,
                  shift_warm_start,
                  solve_axes,
                  solve_box_qp,
)

__all__ = ["SafetyFilter", "Passthrough", "FILTERS", "register_filter", "CBF", "cbf_coefficients", "cbf_constraints",
           "AxisProblem", "axis_problem", "solve_axes", "shift_warm_start", "condensed_qp", "condensed_hessian",
           "condensed_linear", "prediction_matrices", "augmented_weights", "fista", "solve_box_qp"]

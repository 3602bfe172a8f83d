"""Control: the tracking MPC (paper eq. 8–12), the safety filters between it and the plant, and the
disturbance estimators that make its tracking offset-free."""

from .cbf import CBF, braking_constraints, cbf_coefficients, cbf_constraints
from .estimators import ESTIMATORS, Estimator, Integral, NoEstimator, Observer, register_estimator
from .filters import FILTERS, Passthrough, SafetyFilter, register_filter
from .mpc import (
                  MPC_GAINS,
                  AxisProblem,
                  augmented_weights,
                  axis_problem,
                  condensed_hessian,
                  condensed_linear,
                  condensed_qp,
                  fista,
                  prediction_matrices,
                  scales_set,
                  shift_warm_start,
                  solve_axes,
                  solve_box_qp,
)

__all__ = ["SafetyFilter", "Passthrough", "FILTERS", "register_filter", "CBF", "braking_constraints",
           "cbf_coefficients", "cbf_constraints",
           "Estimator", "NoEstimator", "Observer", "Integral", "ESTIMATORS", "register_estimator",
           "MPC_GAINS", "scales_set", "AxisProblem", "axis_problem", "solve_axes", "shift_warm_start", "condensed_qp",
           "condensed_hessian", "condensed_linear", "prediction_matrices", "augmented_weights", "fista", "solve_box_qp"]

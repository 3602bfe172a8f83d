"""Planners: what turns the UAV's state and the obstacles into the MPC's reference (SPEC 3–4).

========================  =================================================================
:mod:`.base`              the :class:`Planner` protocol (``init``/``reference``) and :data:`PLANNERS`
:mod:`.apf`               potential-field planners (:class:`APF`): the saturated gradient flow
:mod:`.weights`           repulsive weights ω (:class:`Weight`), paper eq. 14–20
:mod:`.potentials`        attractive and weighted repulsive potentials and their forces
:mod:`.sight`             the line of sight, component by component
:mod:`.vortex`            a vortex force term (:class:`Vortex`) and the ``vortex`` planner
:mod:`.goal_distance`     Ge–Cui's goal-distance weight (:class:`GoalDistance`), planner ``ge_cui_bounded``
:mod:`.escape`            stall escape (:class:`StallEscape`), planners ``basic_escape``, ``direction_velocity_escape``
:mod:`.velocity_obstacle` velocity obstacles, ORCA (:class:`VelocityObstacle`), planner ``velocity_obstacle``
:mod:`.mppi`              model predictive path integral control (:class:`MPPI`), planner ``mppi``
:mod:`.keepout_mpc`       MPC keeping every obstacle out over its horizon (:class:`KeepoutMPC`), planner ``keepout_mpc``
:mod:`.learned`           a learned weight ω_θ (:class:`LearnedWeight`), planner ``learned_weight``
========================  =================================================================
"""

from .apf import APF, ForceTerm, saturate
from .base import PLANNERS, Planner, reference_states, register_planner
from .escape import StallEscape
from .goal_distance import GoalDistance
from .keepout_mpc import KeepoutMPC
from .learned import LearnedWeight
from .mppi import MPPI
from .sight import Sight
from .velocity_obstacle import VelocityObstacle
from .vortex import Vortex
from .weights import Basic, Direction, DirectionVelocity, Weight

__all__ = ["Planner", "PLANNERS", "register_planner", "reference_states", "APF", "ForceTerm", "saturate", "Weight",
           "Sight", "Basic", "Direction", "DirectionVelocity", "Vortex",
           "GoalDistance", "StallEscape", "VelocityObstacle", "MPPI", "KeepoutMPC", "LearnedWeight"]

"""Scenario families (SPEC 5): obstacle fields as pure functions of a PRNG key and parameters.

==================  ====================================================================
:mod:`.base`        :class:`FamilyParams`, the family registry :data:`FAMILIES`, parameter checks
:mod:`.layout`      the builders' toolkit: a field's random numbers, obstacles in the local frame
:mod:`.families`    the built-in families (``paper_static``, ``trap``, ``clutter``, ...)
:mod:`.generate`    keys, the world frame, clear endpoints, :func:`make_scenarios`
:mod:`.solvability` the solvability oracle :func:`solvable`: could any planner fly a field?
==================  ====================================================================
"""

from .base import FAMILIES, SHAPES, Family, FamilyParams, family_params, register_family
from .families import (
                       TRAP_KINDS,
                       ClutterParams,
                       CrossingParams,
                       DynamicParams,
                       HeadOnParams,
                       MovingParams,
                       OvertakeParams,
                       PaperDynamicParams,
                       PaperStaticParams,
                       TrapParams,
)
from .generate import clear_endpoints, field_key, make_scenario, make_scenarios
from .layout import Draws, Layout
from .solvability import reach_cell, solvable, solvable_field

__all__ = ["FAMILIES", "Family", "FamilyParams", "register_family", "family_params", "SHAPES", "TRAP_KINDS",
           "PaperStaticParams", "PaperDynamicParams", "TrapParams", "ClutterParams", "DynamicParams", "MovingParams",
           "CrossingParams", "HeadOnParams", "OvertakeParams", "field_key", "clear_endpoints", "make_scenario",
           "make_scenarios", "Draws", "Layout", "solvable", "solvable_field", "reach_cell"]

"""Scenario family parameters and the family registry (SPEC 5).

A family is a frozen, hashable :class:`FamilyParams` subclass (its parameters, validated on
construction; a static argument of ``jit``) and a builder that lays out one field's obstacles in
the family's local frame from a block of random numbers (:mod:`jaxapf.scenarios.layout`). Register
one with :func:`register_family`; ``families = [NAME]`` in sweep and tune specs, ``--family NAME``
and ``[scenario.params.NAME]`` then work for it (``docs/extending.md``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, ClassVar, Mapping

from ..registry import Registry
from ..validation import ConfigError, check_choice, check_int, check_names, check_number, check_span

__all__ = ["SHAPES", "Check", "integer", "number", "span", "choice", "names", "FamilyParams", "Family", "FAMILIES",
           "register_family", "family_params", "checked_params"]

SHAPES: tuple[str, ...] = ("cylinder", "sphere")

# --------------------------------------------------------------------------------------------
# parameter checks: what a family's CHECKS table maps each parameter to
# --------------------------------------------------------------------------------------------

#: ``check(where, value) -> normalised value``, raising ConfigError naming ``where``.
Check = Callable[[str, Any], Any]


def integer(lo: int, hi: int | None = None) -> Check:
    """An integer in ``lo … hi``."""
    return lambda where, value: check_int(where, value, lo, hi)


def number(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False) -> Check:
    """A finite number in the range."""
    return lambda where, value: check_number(where, value, lo, hi, lo_open=lo_open)


def span(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, integer: bool = False) -> Check:
    """An interval ``(a, b)``, ``a <= b``, whose ends lie in the range (a number ``x`` means ``(x, x)``)."""
    return lambda where, value: check_span(where, value, lo, hi, lo_open=lo_open, integer=integer)


def choice(choices: tuple[str, ...]) -> Check:
    """One of ``choices``."""
    return lambda where, value: check_choice(where, value, choices)


def names(choices: tuple[str, ...], what: str = "name") -> Check:
    """One or more distinct names of ``choices`` (each a ``what``), in their canonical order."""
    return lambda where, value: check_names(where, value, choices, what=what, canonical=True)


@dataclasses.dataclass(frozen=True)
class FamilyParams:
    """Parameters every family has (defaults shown are the base ones; families override some).

    Attributes:
      max_obstacles: obstacle slots per field (static; integer >= 1). Unused slots are invalid.
      r_uav: UAV radius [m] >= 0 used to keep start and goal clear (engine default 0.3 m).
      start_margin: clearance [m] >= 0 that the start keeps from every obstacle at t = 0
        (default 0.25 m), see :func:`~jaxapf.scenarios.generate.clear_endpoints`.
      goal_margin: clearance [m] >= 0 that the goal keeps from every obstacle at t = 0 (default
        4 m, the default influence distance ``d_s``: no repulsion at the goal at t = 0, so a family
        does not silently include GNRON fields, goals non-reachable with obstacles nearby; ``trap``,
        whose ``gnron`` kind means them, and the families of passing movers keep 0.25 m).
      altitude: z [m] of start, goal and obstacle centres (default 2 m).
      t_max: recommended episode length [s] > 0 (default 60 s: 3–5× the nominal flight time).
      distance: start–goal distance range [m] > 0, drawn uniformly (default 20–30 m).
      heading: range [deg] within [-360, 360] of the start–goal heading about z, drawn uniformly
        (default 0–360°, i.e. any direction).
      shape: ``cylinder`` (vertical, infinitely tall; default) or ``sphere``.

    Every field's unit is in :attr:`UNITS` (a family adds its own), so :meth:`scaled` can shrink a family to
    another vehicle's envelope.
    """

    family: ClassVar[str] = "base"
    #: ``(per field, per obstacle slot)``: the size of a field's block of uniforms is
    #: ``draws[0] + draws[1] · max_obstacles`` (:class:`~jaxapf.scenarios.layout.Draws`); changing it
    #: changes every number the block holds, so a family keeps its own once published.
    draws: ClassVar[tuple[int, int]] = (16, 6)
    CHECKS: ClassVar[Mapping[str, Check]] = {
        "max_obstacles": integer(1),
        "r_uav": number(0.0),
        "start_margin": number(0.0),
        "goal_margin": number(0.0),
        "altitude": number(),
        "t_max": number(0.0, lo_open=True),
        "distance": span(0.0, lo_open=True),
        "heading": span(-360.0, 360.0),
        "shape": choice(SHAPES),
    }
    #: Every field's unit: ``m``, ``m/s``, ``s`` and ``1/m²`` change under :meth:`scaled`, the others
    #: (``""``, ``deg``, a count, a fraction) do not.
    UNITS: ClassVar[Mapping[str, str]] = {
        "max_obstacles": "", "r_uav": "m", "start_margin": "m", "goal_margin": "m", "altitude": "m", "t_max": "s",
        "distance": "m", "heading": "deg", "shape": "",
    }

    max_obstacles: int = 16
    r_uav: float = 0.3
    start_margin: float = 0.25
    goal_margin: float = 4.0
    altitude: float = 2.0
    t_max: float = 60.0
    distance: tuple[float, float] = (20.0, 30.0)
    heading: tuple[float, float] = (0.0, 360.0)
    shape: str = "cylinder"

    def __post_init__(self) -> None:
        where = f"scenario.{self.family}"
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, self.CHECKS[f.name](f"{where}.{f.name}", getattr(self, f.name)))
        self._check(where)

    def _check(self, where: str) -> None:
        """Constraints between fields (checked after every field is valid on its own)."""

    def scaled(self, length: float = 1.0, speed: float = 1.0) -> FamilyParams:
        """The same family shrunk (or grown) to another vehicle: every length × ``length``, every speed ×
        ``speed``, every time × ``length / speed`` and every density per area × ``1 / length²`` (so a field
        holds as many obstacles), the rest kept. Fields drawn from the same key are then the original's
        positions × ``length`` and velocities × ``speed``, but for the fixed 1 mm by which
        :func:`~jaxapf.scenarios.generate.clear_endpoints` pushes an obstacle past its margin."""
        factor = {"m": length, "m/s": speed, "s": length / speed, "1/m²": 1.0 / length ** 2}
        changed = {}
        for name, unit in self.UNITS.items():
            if unit in factor:
                value = getattr(self, name)
                changed[name] = (tuple(factor[unit] * v for v in value) if isinstance(value, tuple)
                                 else factor[unit] * value)
        return dataclasses.replace(self, **changed)



@dataclasses.dataclass(frozen=True)
class Family:
    """A registered family.

    Attributes:
      params: its :class:`FamilyParams` subclass (``params.family`` is the name).
      build: ``build(draws, params, length) -> (Layout, kind)``: the obstacles in the local frame (start at
        the origin, goal at ``(length, 0)``) and the index of the kind drawn, from the field's
        :class:`~jaxapf.scenarios.layout.Draws`.
      kinds: the kinds of field it draws (one name if it draws one kind).
      description: one line for ``jaxapf list families``.
      defining: the kind that shows what the family is about, which ``jaxapf simulate --family`` flies
        by default (default the first of ``kinds``; ``trap``'s is the concave cup).
    """

    params: type[FamilyParams]
    build: Callable[..., Any]
    kinds: tuple[str, ...]
    description: str = ""
    defining: str = ""

    def __post_init__(self) -> None:
        if self.defining and self.defining not in self.kinds:
            raise ConfigError(f"family {self.params.family}: defining kind {self.defining!r} is not one of its kinds "
                              f"({', '.join(self.kinds)})")
        object.__setattr__(self, "defining", self.defining or self.kinds[0])

    @property
    def name(self) -> str:
        return self.params.family


def _describe(family: Family) -> str:
    return f"{family.description} (kinds: {', '.join(family.kinds)})"


#: Registered scenario families.
FAMILIES: Registry[Family] = Registry("family", describe=_describe, listed_as="families")


def register_family(params: type[FamilyParams], build: Callable[..., Any], kinds: tuple[str, ...] | None = None,
                    *, description: str = "", replace: bool = False, defining: str = "") -> Family:
    """Register the family ``params.family`` with its builder and kinds (default: one kind, its name) and the
    kind that defines it (:attr:`Family.defining`)."""
    family = Family(params, build, tuple(kinds or (params.family,)), description, defining)
    return FAMILIES.register(params.family, family, replace=replace)


def family_params(family: str, **overrides: Any) -> FamilyParams:
    """The default parameters of ``family`` with ``overrides`` applied (and validated).

    Raises :class:`ConfigError` for an unknown family, an unknown parameter name (listing the
    allowed ones) or a value out of range.
    """
    return checked_params(FAMILIES.get(family, "scenario.family").params, family, overrides)


def checked_params(cls: type[FamilyParams], family: str, overrides: Mapping[str, Any]) -> FamilyParams:
    """``cls(**overrides)``, an unknown parameter name refused in one line listing the allowed ones."""
    fields = tuple(f.name for f in dataclasses.fields(cls))
    for name in overrides:
        if name not in fields:
            raise ConfigError(f"scenario.{family}.{name} is not a parameter of {family}; allowed: {', '.join(fields)}")
    return cls(**overrides)

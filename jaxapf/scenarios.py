r"""Scenario families (SPEC 5): obstacle fields as pure functions of a PRNG key and parameters.

Every field is built the same way:

1. **Frame.** The start–goal distance ``L`` is drawn uniformly from ``params.distance`` and the
   heading ψ of the start–goal line (a rotation about z) uniformly from ``params.heading``
   (degrees). The start is always ``(0, 0, altitude)``, the goal ``(L cos ψ, L sin ψ, altitude)``.
2. **Layout.** The family lays its obstacles out in a *local* frame: start at the origin, goal at
   ``(L, 0)``, x along the start–goal line, y to its left. Obstacles live in the plane of flight
   (centre z = ``altitude``; cylinders are infinitely tall anyway) and move horizontally.
3. **World.** Positions and velocities are rotated by ψ, padded to exactly ``max_obstacles`` slots
   and passed through :func:`clear_endpoints`, which keeps start and goal at least
   ``endpoint_margin`` clear of every obstacle at t = 0. Padded (invalid) slots are parked at
   ``1e6`` with radius 0 and velocity 0.

Keys: field ``i`` of seed ``s`` uses :func:`field_key` ``= fold_in(key(s), i)``, and a field is
bit-identical whatever batch it is computed in, so chunked sweeps give the same fields (see
:func:`make_scenarios`). A field draws one block of uniforms from its key (one threefry call: each
call site costs XLA compile time) and hands them out in a fixed order, frame first, then layout;
the trap family builds every kind from its own part of the block, so selecting fewer trap kinds
does not change the geometry of the kinds that remain.

Scales follow the engine's defaults: ``v_max = 2 m/s`` per axis, ``a_max = 3 m/s²``, UAV radius
``r_uav = 0.3 m``, APF influence distance ``d_s = 4 m``, ``dt = 0.1 s``. Start–goal distances are
20–30 m (10–15 s at a nominal 1.6 m/s = 0.8·v_max) except for the paper's long scenario 2; obstacle
radii are 0.5–1.5 m. The families and their default numbers (each documented on its parameter
class):

``paper_static`` (:class:`PaperStaticParams`)
    The paper's scenario 1, a classic concave trap for the basic APF: 5 cylinders of radius 1 m on a
    half circle of radius 3 m whose open side faces the start, centred on the start–goal line at the
    middle of a 24 m run along +x. Neighbouring surfaces are 0.30 m apart (< 0.6 m, the UAV's
    diameter), so the cup is closed. Deterministic (optional tiny jitter, default 0).
``paper_dynamic`` (:class:`PaperDynamicParams`)
    The paper's scenario 2: 14 cylinders (radius 0.8–1.5 m) scattered uniformly in a 12 m wide
    corridor along a 70 m diagonal run (heading 45°), 4 of them drifting at 0.1–0.3 m/s;
    recommended episode 300 s.
``trap`` (:class:`TrapParams`)
    One randomized local-minimum trap per field, its kind drawn uniformly from ``kinds``:
    ``on_line`` (one obstacle on the line, lateral offset ≤ 0.3 m), ``concave`` (a closed 5-cylinder
    cup of radius 2.5–4 m facing the start), ``narrow_gap`` (two obstacles 2·r_uav + 0.1–0.6 m
    apart), ``gnron`` (goal 0.5–2 m from an obstacle surface, i.e. inside d_s).
``clutter`` (:class:`ClutterParams`)
    A static forest: ``round(density · area / 100)`` (capped at ``max_obstacles``) cylinders of
    radius 0.5–1.2 m, uniform in the ``L × 12 m`` corridor; default density 4 per 100 m².
``crossing`` (:class:`CrossingParams`)
    1–3 obstacles crossing the line perpendicularly at 0.5–1.5 m/s, each reaching the line at
    30–70 % of the run when a UAV at 1.6 m/s would, ± 2 s.
``head_on`` (:class:`HeadOnParams`)
    1–2 obstacles starting at 60–90 % of the run (lateral offset ≤ 0.5 m) and flying toward the
    start along the line at 0.5–1.5 m/s.
``overtake`` (:class:`OvertakeParams`)
    1–2 obstacles starting 4–10 m behind the start (lateral offset ≤ 0.5 m) and flying toward the
    goal at 3–5 m/s (1.5–2.5 × v_max), i.e. overtaking the UAV: the case the velocity term is for.
``dynamic`` (:class:`DynamicParams`)
    ``clutter`` whose obstacles all move in uniformly random horizontal directions at 0.2–1 m/s.

The paper gives no numbers for its scenarios. The ones here are chosen from the vehicle's scales
and the classic APF failure modes, and none is tuned to make a particular method win.

Parameters are frozen, hashable dataclasses (static arguments of ``jit``), validated on
construction; :func:`family_params` builds one from a family name and overrides.
"""

from __future__ import annotations

import dataclasses
import math
from functools import partial
from typing import Any, Callable, ClassVar, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .config import ConfigError, check_choice, check_int, check_range
from .obstacles import Obstacles, Scenario, project

__all__ = [
    "FAMILIES",
    "TRAP_KINDS",
    "SHAPES",
    "FamilyParams",
    "PaperStaticParams",
    "PaperDynamicParams",
    "TrapParams",
    "ClutterParams",
    "DynamicParams",
    "MovingParams",
    "CrossingParams",
    "HeadOnParams",
    "OvertakeParams",
    "family_params",
    "field_key",
    "make_scenario",
    "make_scenarios",
    "clear_endpoints",
]

FAMILIES: tuple[str, ...] = (
    "paper_static",
    "paper_dynamic",
    "trap",
    "clutter",
    "crossing",
    "head_on",
    "overtake",
    "dynamic",
)
#: Trap kinds of the ``trap`` family.
TRAP_KINDS: tuple[str, ...] = ("on_line", "concave", "narrow_gap", "gnron")
SHAPES: tuple[str, ...] = ("cylinder", "sphere")

#: Cylinders in a concave cup (paper_static and the trap kind ``concave``).
_CUP_SIZE = 5
#: Obstacle slots each trap kind needs.
_TRAP_SIZES: Mapping[str, int] = {"on_line": 1, "concave": _CUP_SIZE, "narrow_gap": 2, "gnron": 1}
#: Where padded slots are parked [m] (matches :meth:`Obstacles.empty`).
_PARK = 1e6
#: :func:`clear_endpoints` pushes to ``margin + _PUSH_SLACK`` [m] so that float rounding of the
#: moved centre can never leave it below ``margin``.
_PUSH_SLACK = 1e-3

# --------------------------------------------------------------------------------------------
# parameter validation
# --------------------------------------------------------------------------------------------

Check = Callable[[str, Any], Any]


def _int(lo: int) -> Check:
    return lambda where, value: check_int(where, value, lo)


def _num(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False) -> Check:
    return lambda where, value: float(check_range(where, value, lo, hi, lo_open=lo_open))


def _span(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
          integer: bool = False) -> Check:
    """An interval ``(lo, hi)`` whose ends lie in the range; a single number ``x`` means ``(x, x)``."""

    def check(where: str, value: Any) -> tuple:
        ends = tuple(value) if isinstance(value, (list, tuple, np.ndarray)) else (value, value)
        if len(ends) != 2:
            raise ConfigError(f"{where} = {value!r} must be a number or a pair (lo, hi)")
        if integer:
            a, b = (check_int(where, e, int(lo)) for e in ends)
        else:
            a, b = (float(check_range(where, e, lo, hi, lo_open=lo_open)) for e in ends)
        if a > b:
            raise ConfigError(f"{where} = {value!r} is not an interval; allowed: a pair (lo, hi) with lo <= hi")
        return (a, b)

    return check


def _choice(choices: tuple[str, ...]) -> Check:
    return lambda where, value: check_choice(where, value, choices)


def _subset(choices: tuple[str, ...]) -> Check:
    """One or more distinct names out of ``choices`` (a single name is allowed); canonical order."""

    def check(where: str, value: Any) -> tuple[str, ...]:
        names = tuple(value) if isinstance(value, (list, tuple)) else (value,)
        for name in names:
            check_choice(where, name, choices)
        if not names or len(set(names)) != len(names):
            raise ConfigError(f"{where} = {value!r} must list one or more distinct names of {', '.join(choices)}")
        return tuple(c for c in choices if c in names)

    return check


@dataclasses.dataclass(frozen=True)
class FamilyParams:
    """Parameters every family has (defaults shown are the base ones; families override some).

    Attributes:
      max_obstacles: obstacle slots per field (static; integer >= 1). Unused slots are invalid.
      r_uav: UAV radius [m] >= 0 used to keep start and goal clear (engine default 0.3 m).
      endpoint_margin: clearance [m] >= 0 that start and goal keep from every obstacle at t = 0
        (default 0.25 m), see :func:`clear_endpoints`.
      altitude: z [m] of start, goal and obstacle centres (default 2 m).
      t_max: recommended episode length [s] > 0 (default 60 s: 3–5× the nominal flight time).
      distance: start–goal distance range [m] > 0, drawn uniformly (default 20–30 m).
      heading: range [deg] within [-360, 360] of the start–goal heading about z, drawn uniformly
        (default 0–360°, i.e. any direction).
      shape: ``cylinder`` (vertical, infinitely tall; default) or ``sphere``.
    """

    family: ClassVar[str] = "base"
    CHECKS: ClassVar[Mapping[str, Check]] = {
        "max_obstacles": _int(1),
        "r_uav": _num(0.0),
        "endpoint_margin": _num(0.0),
        "altitude": _num(),
        "t_max": _num(0.0, lo_open=True),
        "distance": _span(0.0, lo_open=True),
        "heading": _span(-360.0, 360.0),
        "shape": _choice(SHAPES),
    }

    max_obstacles: int = 16
    r_uav: float = 0.3
    endpoint_margin: float = 0.25
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


@dataclasses.dataclass(frozen=True)
class PaperStaticParams(FamilyParams):
    """``paper_static``: the paper's scenario 1, a concave cluster that traps the basic APF.

    Start (0, 0, 2), goal (24, 0, 2) (``distance = 24``, ``heading = 0``). Five cylinders of
    ``radius = 1 m`` sit on a half circle of ``cup_radius = 3 m`` (at -90°, -45°, 0°, 45°, 90° from
    +x) whose open side faces the start; the cup's middle is at the middle of the run, on the line.
    Neighbouring surfaces are 2·3·sin 22.5° - 2 = 0.30 m apart, narrower than the UAV (0.6 m),
    so the cup is closed and the attraction pulls the UAV straight into it. ``jitter`` (default
    0 m, at most 1 m) moves every centre by a key-dependent uniform offset in [-jitter, jitter]²;
    with 0 the field does not depend on the key. ``max_obstacles`` defaults to (and must be at
    least) 5.
    """

    family = "paper_static"
    CHECKS = FamilyParams.CHECKS | {
        "radius": _num(0.0, lo_open=True),
        "cup_radius": _num(0.0, lo_open=True),
        "jitter": _num(0.0, 1.0),
    }

    max_obstacles: int = _CUP_SIZE
    distance: tuple[float, float] = (24.0, 24.0)
    heading: tuple[float, float] = (0.0, 0.0)
    radius: float = 1.0
    cup_radius: float = 3.0
    jitter: float = 0.0

    def _check(self, where: str) -> None:
        check_int(f"{where}.max_obstacles", self.max_obstacles, _CUP_SIZE)


@dataclasses.dataclass(frozen=True)
class PaperDynamicParams(FamilyParams):
    """``paper_dynamic``: the paper's scenario 2, a long run through clutter with moving obstacles.

    Start (0, 0, 2), goal 70 m away on the diagonal (``distance = 70``, ``heading = 45°``), i.e.
    about (49.5, 49.5, 2); recommended ``t_max = 300 s`` (the paper's horizon; the straight line
    takes ~44 s at 1.6 m/s). ``count = 14`` cylinders with radii uniform in ``radius = 0.8–1.5 m``
    are placed uniformly in the corridor ``0 <= x <= L``, ``|y| <= width/2 = 6 m``; the first
    ``n_moving = 4`` of them drift in uniformly random horizontal directions at
    ``speed = 0.1–0.3 m/s`` (slow, so they stay near the corridor while the UAV crosses it), the
    rest are static. ``max_obstacles = 16`` (``count`` must not exceed it).
    """

    family = "paper_dynamic"
    CHECKS = FamilyParams.CHECKS | {
        "count": _int(1),
        "n_moving": _int(0),
        "width": _num(0.0, lo_open=True),
        "radius": _span(0.0, lo_open=True),
        "speed": _span(0.0),
    }

    t_max: float = 300.0
    distance: tuple[float, float] = (70.0, 70.0)
    heading: tuple[float, float] = (45.0, 45.0)
    count: int = 14
    n_moving: int = 4
    width: float = 12.0
    radius: tuple[float, float] = (0.8, 1.5)
    speed: tuple[float, float] = (0.1, 0.3)

    def _check(self, where: str) -> None:
        check_int(f"{where}.count", self.count, 1, self.max_obstacles)
        check_int(f"{where}.n_moving", self.n_moving, 0, self.count)


@dataclasses.dataclass(frozen=True)
class TrapParams(FamilyParams):
    """``trap``: one randomized local-minimum trap per field, kind drawn uniformly from ``kinds``.

    Every trap is centred at a fraction ``along = 0.4–0.6`` of the run (uniform), with a lateral
    offset uniform in ``[-offset, offset]``, ``offset = 0.3 m``. Kinds:

    - ``on_line``: one obstacle of radius uniform in ``radius = 0.5–1.5 m`` on the line.
    - ``concave``: a cup of 5 cylinders on a half circle of radius uniform in
      ``cup_radius = 2.5–4 m``, open side toward the start; each cylinder's radius is
      ``cup_radius · sin 22.5°`` (0.96–1.53 m) so neighbours touch and the cup is closed.
    - ``narrow_gap``: two obstacles of the same radius (``radius``) either side of the line whose
      surfaces are ``2 r_uav + gap_slack`` apart, ``gap_slack = 0.1–0.6 m``: the UAV fits, with
      0.05–0.3 m to spare on each side.
    - ``gnron`` (goal near obstacle): one obstacle (``radius``) whose surface is
      ``goal_clearance = 0.5–2 m`` (UAV clearance) from the goal, in a uniformly random direction;
      the goal lies inside the influence distance d_s = 4 m.

    ``max_obstacles`` defaults to 5 and must hold the largest selected kind (concave 5, narrow_gap
    2, on_line and gnron 1).
    """

    family = "trap"
    CHECKS = FamilyParams.CHECKS | {
        "kinds": _subset(TRAP_KINDS),
        "along": _span(0.0, 1.0),
        "offset": _num(0.0),
        "radius": _span(0.0, lo_open=True),
        "cup_radius": _span(0.0, lo_open=True),
        "gap_slack": _span(0.0),
        "goal_clearance": _span(0.0),
    }

    max_obstacles: int = _CUP_SIZE
    kinds: tuple[str, ...] = TRAP_KINDS
    along: tuple[float, float] = (0.4, 0.6)
    offset: float = 0.3
    radius: tuple[float, float] = (0.5, 1.5)
    cup_radius: tuple[float, float] = (2.5, 4.0)
    gap_slack: tuple[float, float] = (0.1, 0.6)
    goal_clearance: tuple[float, float] = (0.5, 2.0)

    def _check(self, where: str) -> None:
        check_int(f"{where}.max_obstacles", self.max_obstacles, max(_TRAP_SIZES[k] for k in self.kinds))


@dataclasses.dataclass(frozen=True)
class ClutterParams(FamilyParams):
    """``clutter``: a random static forest.

    ``round(density · L · width / 100)`` obstacles, capped at ``max_obstacles = 16``, with centres
    uniform in the corridor ``0 <= x <= L``, ``|y| <= width/2`` (``width = 12 m``) and radii
    uniform in ``radius = 0.5–1.2 m``; obstacles may overlap (compound obstacles). Default
    ``density = 4`` per 100 m² gives 10–14 obstacles on the 20–30 m runs and covers ~7 % of the
    corridor.
    """

    family = "clutter"
    CHECKS = FamilyParams.CHECKS | {
        "density": _num(0.0),
        "width": _num(0.0, lo_open=True),
        "radius": _span(0.0, lo_open=True),
    }

    density: float = 4.0
    width: float = 12.0
    radius: tuple[float, float] = (0.5, 1.2)


@dataclasses.dataclass(frozen=True)
class DynamicParams(ClutterParams):
    """``dynamic``: :class:`ClutterParams` whose every obstacle moves at constant velocity, in a
    uniformly random horizontal direction, at a speed uniform in ``speed = 0.2–1.0 m/s``
    (at most half the UAV's per-axis limit)."""

    family = "dynamic"
    CHECKS = ClutterParams.CHECKS | {"speed": _span(0.0)}

    speed: tuple[float, float] = (0.2, 1.0)


@dataclasses.dataclass(frozen=True)
class MovingParams(FamilyParams):
    """Common to ``crossing``, ``head_on`` and ``overtake``: a number of moving obstacles uniform in
    the integers ``count`` (whose upper end must not exceed ``max_obstacles``), each with a radius
    uniform in ``radius`` [m] and a speed uniform in ``speed`` [m/s]."""

    CHECKS = FamilyParams.CHECKS | {
        "count": _span(1, integer=True),
        "radius": _span(0.0, lo_open=True),
        "speed": _span(0.0),
    }

    count: tuple[int, int] = (1, 2)
    radius: tuple[float, float] = (0.5, 1.0)
    speed: tuple[float, float] = (0.5, 1.5)

    def _check(self, where: str) -> None:
        check_int(f"{where}.count", self.count[1], 1, self.max_obstacles)


@dataclasses.dataclass(frozen=True)
class CrossingParams(MovingParams):
    """``crossing``: ``count = 1–3`` obstacles (``max_obstacles = 3``, radius 0.5–1.0 m) crossing
    the start–goal line perpendicularly (from a random side) at ``speed = 0.5–1.5 m/s``.

    Obstacle i crosses the line at ``x_i = meet_i · L`` with ``meet = 0.3–0.7``, at the time
    ``x_i / uav_speed + δ_i`` a UAV flying the straight line at ``uav_speed = 1.6 m/s``
    (0.8·v_max) would get there, ``δ_i`` uniform in ``timing = -2…2 s`` (the ~0.3 s the UAV needs
    to spin up from rest is ignored).
    """

    family = "crossing"
    CHECKS = MovingParams.CHECKS | {
        "meet": _span(0.0, 1.0),
        "timing": _span(),
        "uav_speed": _num(0.0, lo_open=True),
    }

    max_obstacles: int = 3
    count: tuple[int, int] = (1, 3)
    meet: tuple[float, float] = (0.3, 0.7)
    timing: tuple[float, float] = (-2.0, 2.0)
    uav_speed: float = 1.6


@dataclasses.dataclass(frozen=True)
class HeadOnParams(MovingParams):
    """``head_on``: ``count = 1–2`` obstacles (``max_obstacles = 2``, radius 0.5–1.0 m) starting at
    a fraction ``along = 0.6–0.9`` of the run with a lateral offset uniform in ``±offset``
    (``offset = 0.5 m``) and flying toward the start, parallel to the line, at
    ``speed = 0.5–1.5 m/s`` (closing speed with a UAV at 1.6 m/s 2.1–3.1 m/s: they meet after
    about 4–13 s)."""

    family = "head_on"
    CHECKS = MovingParams.CHECKS | {"along": _span(0.0, 1.0), "offset": _num(0.0)}

    max_obstacles: int = 2
    along: tuple[float, float] = (0.6, 0.9)
    offset: float = 0.5


@dataclasses.dataclass(frozen=True)
class OvertakeParams(MovingParams):
    """``overtake``: ``count = 1–2`` obstacles (``max_obstacles = 2``, radius 0.5–1.0 m) starting
    ``behind = 4–10 m`` behind the start with a lateral offset uniform in ``±offset``
    (``offset = 0.5 m``) and flying toward the goal, parallel to the line, at
    ``speed = 3–5 m/s`` (1.5–2.5 × v_max = 2 m/s), so they catch up with the UAV from behind."""

    family = "overtake"
    CHECKS = MovingParams.CHECKS | {"behind": _span(0.0, lo_open=True), "offset": _num(0.0)}

    max_obstacles: int = 2
    speed: tuple[float, float] = (3.0, 5.0)
    behind: tuple[float, float] = (4.0, 10.0)
    offset: float = 0.5


# --------------------------------------------------------------------------------------------
# random numbers and geometry helpers (local frame: start at the origin, goal at (L, 0), xy only)
# --------------------------------------------------------------------------------------------


class _Draws:
    """A field's random numbers, handed out in order from one block of uniforms in [0, 1).

    One ``jax.random.uniform`` call per field instead of one per quantity: every threefry call
    site adds a noticeable fraction of a second of XLA compile time on CPU, while the block's size
    costs nothing. The block holds ``_DRAWS_PER_FIELD + _DRAWS_PER_SLOT · max_obstacles`` numbers;
    asking for more is a programming error caught while tracing.
    """

    def __init__(self, u: Array) -> None:
        self._u = u
        self._used = 0

    def uniform(self, span: tuple, shape: tuple[int, ...] = ()) -> Array:
        """Uniform in ``[lo, hi)``; exactly ``lo`` when ``lo == hi``."""
        n = math.prod(shape)
        if self._used + n > self._u.shape[0]:
            raise RuntimeError(f"scenario draw budget of {self._u.shape[0]} numbers exceeded")
        u = self._u[self._used:self._used + n].reshape(shape)
        self._used += n
        lo, hi = span
        return lo + (hi - lo) * u

    def integers(self, lo: int, hi: int, shape: tuple[int, ...] = ()) -> Array:
        """Uniform in the integers ``lo … hi``."""
        return jnp.minimum(jnp.floor(self.uniform((lo, hi + 1), shape)), hi).astype(int)

    def signs(self, shape: tuple[int, ...]) -> Array:
        """±1 with equal probability."""
        return jnp.where(self.uniform((0.0, 1.0), shape) < 0.5, 1.0, -1.0)

    def directions(self, n: int) -> Array:
        """``n`` horizontal unit vectors (n, 2) in uniformly random directions."""
        phi = self.uniform((0.0, 2.0 * math.pi), (n,))
        return jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)


#: Size of a field's block of uniforms (see :class:`_Draws`): the most any family uses is
#: 12 numbers per field plus 5 per slot.
_DRAWS_PER_FIELD, _DRAWS_PER_SLOT = 16, 6


class _Layout(NamedTuple):
    """Obstacles in the local frame, any number K of rows."""

    xy: Array  # (K, 2) centres at t = 0
    vxy: Array  # (K, 2) velocities
    radius: Array  # (K,)
    valid: Array  # (K,) bool


def _static(xy: Array, radius: Array) -> _Layout:
    """Static obstacles, all valid."""
    return _Layout(xy, jnp.zeros_like(xy), radius, jnp.ones(radius.shape, bool))


def _fit(layout: _Layout, size: int) -> _Layout:
    """Exactly ``size`` rows: cut, or followed by invalid rows of zeros. Only rows that are
    invalid are ever cut (parameter validation makes ``max_obstacles`` hold every valid row)."""
    extra = max(size - layout.radius.shape[0], 0)
    return _Layout(*(jnp.concatenate([a[:size], jnp.zeros((extra,) + a.shape[1:], a.dtype)]) for a in layout))


def _cup(mid_x: Array, y: Array, cup_radius: Array | float, radius: Array | float) -> _Layout:
    """``_CUP_SIZE`` cylinders of ``radius`` evenly on a half circle of ``cup_radius`` whose open
    side faces the start (angles -90°…90° from +x); the cup spans ``mid_x ± cup_radius/2`` in x."""
    angles = jnp.linspace(-0.5 * math.pi, 0.5 * math.pi, _CUP_SIZE, dtype=mid_x.dtype)
    centre_x = mid_x - 0.5 * cup_radius
    xy = jnp.stack([centre_x + cup_radius * jnp.cos(angles), y + cup_radius * jnp.sin(angles)], axis=-1)
    return _static(xy, jnp.full((_CUP_SIZE,), radius, mid_x.dtype))


def _scatter(d: _Draws, size: int, count: Array | int, length: Array, width: float,
             radius: tuple[float, float]) -> _Layout:
    """``size`` rows, the first ``count`` valid: centres uniform in ``[0, L] × [-w/2, w/2]``, radii
    uniform in ``radius``, at rest."""
    x = d.uniform((0.0, length), (size,))
    y = d.uniform((-0.5 * width, 0.5 * width), (size,))
    xy = jnp.stack([x, y], axis=-1)
    return _Layout(xy, jnp.zeros_like(xy), d.uniform(radius, (size,)), jnp.arange(size) < count)


def _with_motion(layout: _Layout, d: _Draws, speed: tuple[float, float], moving: Array) -> _Layout:
    """``layout`` whose rows where ``moving`` get random horizontal velocities (speed uniform)."""
    n = layout.radius.shape[0]
    vxy = d.directions(n) * d.uniform(speed, (n, 1))
    return layout._replace(vxy=jnp.where(moving[:, None], vxy, 0.0))


# --------------------------------------------------------------------------------------------
# families: (draws, params, L) -> _Layout in the local frame
# --------------------------------------------------------------------------------------------


def _paper_static(d: _Draws, p: PaperStaticParams, length: Array) -> _Layout:
    cup = _cup(0.5 * length, jnp.zeros_like(length), p.cup_radius, p.radius)
    return cup._replace(xy=cup.xy + d.uniform((-p.jitter, p.jitter), cup.xy.shape))


def _paper_dynamic(d: _Draws, p: PaperDynamicParams, length: Array) -> _Layout:
    field = _scatter(d, p.max_obstacles, p.count, length, p.width, p.radius)
    return _with_motion(field, d, p.speed, jnp.arange(p.max_obstacles) < p.n_moving)


def _trap_on_line(d: _Draws, p: TrapParams, length: Array, x: Array, y: Array) -> _Layout:
    return _static(jnp.stack([x, y])[None], d.uniform(p.radius, (1,)))


def _trap_concave(d: _Draws, p: TrapParams, length: Array, x: Array, y: Array) -> _Layout:
    cup_radius = d.uniform(p.cup_radius)
    return _cup(x, y, cup_radius, cup_radius * math.sin(0.5 * math.pi / (_CUP_SIZE - 1)))


def _trap_narrow_gap(d: _Draws, p: TrapParams, length: Array, x: Array, y: Array) -> _Layout:
    radius = d.uniform(p.radius)
    half = 0.5 * (2.0 * p.r_uav + d.uniform(p.gap_slack)) + radius
    return _static(jnp.stack([jnp.stack([x, y + half]), jnp.stack([x, y - half])]), jnp.stack([radius, radius]))


def _trap_gnron(d: _Draws, p: TrapParams, length: Array, x: Array, y: Array) -> _Layout:
    del x, y  # placed relative to the goal
    radius = d.uniform(p.radius, (1,))
    reach = radius + p.r_uav + d.uniform(p.goal_clearance, (1,))
    goal = jnp.stack([length, jnp.zeros_like(length)])
    return _static(goal + reach[:, None] * d.directions(1), radius)


_TRAP_BUILDERS: Mapping[str, Callable[..., _Layout]] = {
    "on_line": _trap_on_line,
    "concave": _trap_concave,
    "narrow_gap": _trap_narrow_gap,
    "gnron": _trap_gnron,
}


def _trap(d: _Draws, p: TrapParams, length: Array) -> _Layout:
    """Every kind is built (they are tiny) in the order of ``TRAP_KINDS`` so that a kind's geometry
    in a field does not depend on which other kinds are selected; one selected kind is kept."""
    pick = d.integers(0, len(p.kinds) - 1)
    x = d.uniform(p.along) * length
    y = d.uniform((-p.offset, p.offset))
    layouts = {k: _fit(_TRAP_BUILDERS[k](d, p, length, x, y), _CUP_SIZE) for k in TRAP_KINDS}
    return jax.tree.map(lambda *rows: jnp.stack(rows)[pick], *(layouts[k] for k in p.kinds))


def _clutter(d: _Draws, p: ClutterParams, length: Array) -> _Layout:
    count = jnp.minimum(jnp.round(p.density * length * p.width / 100.0), p.max_obstacles)
    return _scatter(d, p.max_obstacles, count, length, p.width, p.radius)


def _dynamic(d: _Draws, p: DynamicParams, length: Array) -> _Layout:
    field = _clutter(d, p, length)
    return _with_motion(field, d, p.speed, field.valid)


def _movers(d: _Draws, p: MovingParams, place: Callable[[Array], tuple[Array, Array]]) -> _Layout:
    """``max_obstacles`` rows, the first ``count`` valid; ``place(speed)`` returns the centres and
    velocities (n, 2) given each row's speed (n,)."""
    n = p.max_obstacles
    count = d.integers(*p.count)
    radius = d.uniform(p.radius, (n,))
    xy, vxy = place(d.uniform(p.speed, (n,)))
    return _Layout(xy, vxy, radius, jnp.arange(n) < count)


def _crossing(d: _Draws, p: CrossingParams, length: Array) -> _Layout:
    def place(speed: Array) -> tuple[Array, Array]:
        x = d.uniform(p.meet, speed.shape) * length
        t_meet = x / p.uav_speed + d.uniform(p.timing, speed.shape)
        vy = d.signs(speed.shape) * speed
        return jnp.stack([x, -vy * t_meet], -1), jnp.stack([jnp.zeros_like(vy), vy], -1)

    return _movers(d, p, place)


def _along_line(d: _Draws, p: HeadOnParams | OvertakeParams, x_span: tuple, sign: float) -> _Layout:
    """Movers starting at x uniform in ``x_span`` (lateral offset ±``p.offset``) and flying parallel
    to the line, toward the goal (``sign = +1``) or toward the start (``sign = -1``)."""

    def place(speed: Array) -> tuple[Array, Array]:
        xy = jnp.stack([d.uniform(x_span, speed.shape), d.uniform((-p.offset, p.offset), speed.shape)], -1)
        return xy, jnp.stack([sign * speed, jnp.zeros_like(speed)], -1)

    return _movers(d, p, place)


def _head_on(d: _Draws, p: HeadOnParams, length: Array) -> _Layout:
    return _along_line(d, p, (p.along[0] * length, p.along[1] * length), -1.0)


def _overtake(d: _Draws, p: OvertakeParams, length: Array) -> _Layout:
    return _along_line(d, p, (-p.behind[1], -p.behind[0]), 1.0)


_BUILDERS: Mapping[type, Callable[[_Draws, Any, Array], _Layout]] = {
    PaperStaticParams: _paper_static,
    PaperDynamicParams: _paper_dynamic,
    TrapParams: _trap,
    ClutterParams: _clutter,
    CrossingParams: _crossing,
    HeadOnParams: _head_on,
    OvertakeParams: _overtake,
    DynamicParams: _dynamic,
}
_PARAMS: Mapping[str, type] = {cls.family: cls for cls in _BUILDERS}
assert tuple(sorted(_PARAMS)) == tuple(sorted(FAMILIES))

# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------


def family_params(family: str, **overrides: Any) -> FamilyParams:
    """The default parameters of ``family`` with ``overrides`` applied (and validated).

    Raises :class:`ConfigError` for an unknown family, an unknown parameter name (listing the
    allowed ones) or a value out of range.
    """
    cls = _PARAMS[check_choice("scenario.family", family, FAMILIES)]
    names = tuple(f.name for f in dataclasses.fields(cls))
    for name in overrides:
        if name not in names:
            raise ConfigError(f"scenario.{family}.{name} is not a parameter of {family}; allowed: {', '.join(names)}")
    return cls(**overrides)


def field_key(seed: int, field_index: int | Array) -> Array:
    """The key of field ``field_index`` of ``seed``: ``fold_in(jax.random.key(seed), field_index)``."""
    return jax.random.fold_in(jax.random.key(seed), field_index)


def _park(obstacles: Obstacles) -> Obstacles:
    """Invalid slots parked at ``1e6`` with radius 0, velocity 0, sphere flag."""
    valid = obstacles.valid
    return Obstacles(
        position=jnp.where(valid[:, None], obstacles.position, _PARK),
        velocity=jnp.where(valid[:, None], obstacles.velocity, 0.0),
        radius=jnp.where(valid, obstacles.radius, 0.0),
        cylinder=obstacles.cylinder & valid,
        valid=valid,
    )


def _sq_norm(r: Array) -> Array:
    """``|r|²`` over the last axis (3), written out: XLA's CPU reductions round differently for
    different batch sizes, and a field must not depend on the batch it is computed in."""
    return r[..., 0] * r[..., 0] + r[..., 1] * r[..., 1] + r[..., 2] * r[..., 2]


def clear_endpoints(obstacles: Obstacles, start: Array, goal: Array, r_uav: float | Array,
                    margin: float | Array) -> Obstacles:
    """Keep ``start`` and ``goal`` at least ``margin`` clear (UAV clearance, t = 0) of every obstacle.

    Deterministic: an obstacle whose clearance from the start is below ``margin`` is moved radially
    away from the start (in xy for a cylinder, in 3-D for a sphere) until its clearance is
    ``margin`` (plus 1 mm against rounding); then the same for the goal. After two such passes an
    obstacle that still violates either end (possible only when start and goal are closer than
    an obstacle's diameter plus margins) is marked invalid. An obstacle centred exactly on an end
    is moved perpendicular to the start–goal line (to its left). Invalid slots come back parked.
    """
    along = goal - start
    left = jnp.stack([-along[1], along[0], jnp.zeros_like(along[0])])
    left_sq = _sq_norm(left)
    unit_y = jnp.array([0.0, 1.0, 0.0], left.dtype)
    fallback = jnp.where(left_sq > 0, left / jnp.sqrt(jnp.where(left_sq > 0, left_sq, 1.0)), unit_y)
    need = obstacles.radius + r_uav + margin  # centre distance at which the clearance is `margin`

    def distance(position: Array, point: Array) -> tuple[Array, Array]:
        rel = project(position - point, obstacles.cylinder)
        return rel, jnp.sqrt(_sq_norm(rel))

    def push(position: Array, point: Array) -> Array:
        rel, dist = distance(position, point)
        direction = jnp.where((dist > 0)[:, None], rel / jnp.where(dist > 0, dist, 1.0)[:, None], fallback)
        move = jnp.where(obstacles.valid & (dist < need), need + _PUSH_SLACK - dist, 0.0)
        return position + direction * move[:, None]

    position = obstacles.position
    for _ in range(2):
        position = push(push(position, start), goal)
    ok = (distance(position, start)[1] >= need) & (distance(position, goal)[1] >= need)
    return _park(dataclasses.replace(obstacles, position=position, valid=obstacles.valid & ok))


def _to_world(xy: Array, heading: Array, z: float) -> Array:
    """Local ``(..., 2)`` rotated by ``heading`` about z, with height ``z``: ``(..., 3)``."""
    c, s = jnp.cos(heading), jnp.sin(heading)
    x, y = xy[..., 0], xy[..., 1]
    return jnp.stack([c * x - s * y, s * x + c * y, jnp.full_like(x, z)], axis=-1)


def _local_field(u: Array, params: FamilyParams) -> tuple[Array, Array, _Layout]:
    """Start–goal distance L, heading ψ [rad] and the local layout (``max_obstacles`` rows) from a
    field's block of uniforms ``u``."""
    d = _Draws(u)
    length = d.uniform(params.distance)
    heading = jnp.deg2rad(d.uniform(params.heading))
    return length, heading, _fit(_BUILDERS[type(params)](d, params, length), params.max_obstacles)


def _place(length: Array, heading: Array, layout: _Layout, altitude: Array, r_uav: Array, margin: Array,
           cylinder: Array) -> Scenario:
    """The field in the world frame, with clear endpoints."""
    zero = jnp.zeros_like(length)
    start = jnp.stack([zero, zero, zero + altitude])
    goal = _to_world(jnp.stack([length, zero]), heading, altitude)
    obstacles = Obstacles(
        position=_to_world(layout.xy, heading, altitude),
        velocity=_to_world(layout.vxy, heading, 0.0),
        radius=layout.radius,
        cylinder=jnp.broadcast_to(cylinder, layout.valid.shape),
        valid=layout.valid,
    )
    return Scenario(start, goal, clear_endpoints(obstacles, start, goal, r_uav, margin))


def _placement(params: FamilyParams) -> tuple[float, float, float, bool]:
    """The arguments of :func:`_place` taken from ``params`` (traced, so they do not recompile)."""
    return params.altitude, params.r_uav, params.endpoint_margin, params.shape == "cylinder"


def _stage_boundary(local: tuple, params: FamilyParams) -> tuple[tuple, tuple]:
    """The local field and the placement arguments behind an optimisation barrier, so that XLA
    neither fuses across the two stages nor folds the placement constants: a field then rounds
    the same whether the stages are compiled separately (:func:`make_scenarios`) or together
    (either function under a caller's ``jit``)."""
    return jax.lax.optimization_barrier((local, _placement(params)))


def _draw_count(params: FamilyParams) -> int:
    """Size of a field's block of uniforms (see :class:`_Draws`)."""
    return _DRAWS_PER_FIELD + _DRAWS_PER_SLOT * params.max_obstacles


def _uniforms(key: Array, size: int) -> Array:
    return jax.random.uniform(key, (size,), jnp.result_type(float))


def make_scenario(key: Array, params: FamilyParams) -> Scenario:
    """One field of ``params.family`` from ``key``: a pure function of both (``params`` is static
    under ``jit``; ``vmap`` over keys gives a batch).

    Floats have JAX's default float dtype (float32, or float64 under ``jax_enable_x64``); the
    obstacle set has exactly ``params.max_obstacles`` slots.
    """
    local, placement = _stage_boundary(_local_field(_uniforms(key, _draw_count(params)), params), params)
    return _place(*local, *placement)


# make_scenarios runs make_scenario as three compiled, batched stages so that the parts that do
# not depend on the family (the random block; world frame + clear_endpoints) compile once per
# shape and are shared by all families with the same max_obstacles.


@partial(jax.jit, static_argnames="size")
def _draw_batch(base_key: Array, indices: Array, size: int) -> Array:
    return jax.vmap(lambda i: _uniforms(jax.random.fold_in(base_key, i), size))(indices)


@partial(jax.jit, static_argnames="params")
def _local_batch(u: Array, params: FamilyParams) -> tuple[Array, Array, _Layout]:
    return jax.vmap(lambda row: _local_field(row, params))(u)


_place_batch = jax.jit(jax.vmap(_place, in_axes=(0, 0, 0, None, None, None, None)))


def make_scenarios(seed: int | Array, params: FamilyParams, fields: int | Array) -> Scenario:
    """A batch of fields (leading axis on every leaf): field ``i`` is
    ``make_scenario(field_key(seed, i), params)``.

    ``fields`` is a count ``n`` (fields ``0 … n-1``) or a 1-D integer array of field indices.
    A field is bit-identical whatever batch it is computed in (so a sweep split into chunks yields
    exactly the fields of the whole sweep, and ``simulate`` on field ``i`` sees the field the
    sweep saw) and whether or not this call or :func:`make_scenario` runs inside a caller's
    ``jit``. (Only op-by-op evaluation of :func:`make_scenario` without ``jit`` may differ in the
    last bit: nothing is fused there.)
    """
    if isinstance(fields, (int, np.integer)) and not isinstance(fields, bool):
        indices = jnp.arange(check_int("scenario.fields", fields, 0))
    else:
        indices = jnp.asarray(fields)
        if indices.ndim != 1 or not jnp.issubdtype(indices.dtype, jnp.integer):
            raise ConfigError(f"scenario.fields must be a count or a 1-D integer array of field indices; "
                              f"got {indices.dtype} of shape {indices.shape}")
    u = _draw_batch(jax.random.key(seed), indices, _draw_count(params))
    local, placement = _stage_boundary(_local_batch(u, params), params)
    return _place_batch(*local, *placement)

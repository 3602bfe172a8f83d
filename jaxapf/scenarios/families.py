r"""The built-in scenario families (SPEC 5), registered: ``paper_static``, ``paper_dynamic``, ``trap``,
``clutter``, ``crossing``, ``head_on``, ``overtake`` and ``dynamic``.

Each is a frozen, hashable parameter class (a static argument of ``jit``, validated on construction;
:func:`~jaxapf.scenarios.family_params` builds one from a name and overrides) whose docstring gives the
family's layout and default numbers, and a layout function in the local frame (start at the origin,
goal at ``(L, 0)``). How every field is built from its key, the frame and the endpoint margins:
docs/scenarios.md, "How a field is built".
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Mapping

import jax
import jax.numpy as jnp
from jax import Array

from ..validation import ConfigError, check_int
from .base import FamilyParams, integer, names, number, register_family, span
from .layout import CUP_SIZE, Draws, Layout, cup, fit, scatter, static, with_motion

__all__ = ["TRAP_KINDS", "PaperStaticParams", "PaperDynamicParams", "TrapParams", "ClutterParams", "DynamicParams",
           "MovingParams", "CrossingParams", "HeadOnParams", "OvertakeParams"]

#: Trap kinds of the ``trap`` family.
TRAP_KINDS: tuple[str, ...] = ("on_line", "concave", "narrow_gap", "gnron")
#: Obstacle slots each trap kind needs.
_TRAP_SIZES: Mapping[str, int] = {"on_line": 1, "concave": CUP_SIZE, "narrow_gap": 2, "gnron": 1}


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
        "radius": number(0.0, lo_open=True),
        "cup_radius": number(0.0, lo_open=True),
        "jitter": number(0.0, 1.0),
    }
    UNITS = FamilyParams.UNITS | {"radius": "m", "cup_radius": "m", "jitter": "m"}

    max_obstacles: int = CUP_SIZE
    distance: tuple[float, float] = (24.0, 24.0)
    heading: tuple[float, float] = (0.0, 0.0)
    radius: float = 1.0
    cup_radius: float = 3.0
    jitter: float = 0.0

    def _check(self, where: str) -> None:
        check_int(f"{where}.max_obstacles", self.max_obstacles, CUP_SIZE)


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
        "count": integer(1),
        "n_moving": integer(0),
        "width": number(0.0, lo_open=True),
        "radius": span(0.0, lo_open=True),
        "speed": span(0.0),
    }
    UNITS = FamilyParams.UNITS | {"count": "", "n_moving": "", "width": "m", "radius": "m", "speed": "m/s"}

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
      ``cup_fill · cup_radius · sin 22.5°`` (0.96–1.53 m at the default ``cup_fill = 1``) so
      neighbours touch and the cup is closed; ``cup_fill < 1`` opens gaps of
      ``2 (1 - cup_fill) cup_radius sin 22.5°`` between neighbours (an easier, leaky cup).
    - ``narrow_gap``: two obstacles of the same radius (``radius``) either side of the line whose
      surfaces are ``2 r_uav + gap_slack`` apart, ``gap_slack = 0.1–0.6 m``: the UAV fits, with
      0.05–0.3 m to spare on each side.
    - ``gnron`` (goal near obstacle): one obstacle (``radius``) whose surface is
      ``goal_clearance = 0.5–2 m`` (UAV clearance) from the goal, in a uniformly random direction;
      the goal lies inside the influence distance d_s = 4 m.

    ``max_obstacles`` defaults to 5 and must hold the largest selected kind (concave 5, narrow_gap
    2, on_line and gnron 1). ``goal_margin`` defaults to 0.25 m and must not exceed the lower end of
    ``goal_clearance`` while ``gnron`` is selected (it would push the obstacle away from the goal).
    """

    family = "trap"
    CHECKS = FamilyParams.CHECKS | {
        "kinds": names(TRAP_KINDS, "kind"),
        "along": span(0.0, 1.0),
        "offset": number(0.0),
        "radius": span(0.0, lo_open=True),
        "cup_radius": span(0.0, lo_open=True),
        "cup_fill": number(0.0, 1.0, lo_open=True),
        "gap_slack": span(0.0),
        "goal_clearance": span(0.0),
    }
    UNITS = FamilyParams.UNITS | {"kinds": "", "along": "", "offset": "m", "radius": "m", "cup_radius": "m",
                                  "cup_fill": "", "gap_slack": "m", "goal_clearance": "m"}

    max_obstacles: int = CUP_SIZE
    kinds: tuple[str, ...] = TRAP_KINDS
    along: tuple[float, float] = (0.4, 0.6)
    offset: float = 0.3
    radius: tuple[float, float] = (0.5, 1.5)
    cup_radius: tuple[float, float] = (2.5, 4.0)
    cup_fill: float = 1.0
    gap_slack: tuple[float, float] = (0.1, 0.6)
    goal_clearance: tuple[float, float] = (0.5, 2.0)
    goal_margin: float = 0.25

    def _check(self, where: str) -> None:
        check_int(f"{where}.max_obstacles", self.max_obstacles, max(_TRAP_SIZES[k] for k in self.kinds))
        if "gnron" in self.kinds and self.goal_margin > self.goal_clearance[0]:
            raise ConfigError(f"{where}.goal_margin = {self.goal_margin:g} exceeds goal_clearance's lower end "
                              f"{self.goal_clearance[0]:g}: it would push the gnron obstacle away from the goal; "
                              "lower goal_margin or drop gnron from kinds")


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
        "density": number(0.0),
        "width": number(0.0, lo_open=True),
        "radius": span(0.0, lo_open=True),
    }
    UNITS = FamilyParams.UNITS | {"density": "1/m²", "width": "m", "radius": "m"}

    density: float = 4.0
    width: float = 12.0
    radius: tuple[float, float] = (0.5, 1.2)


@dataclasses.dataclass(frozen=True)
class DynamicParams(ClutterParams):
    """``dynamic``: :class:`ClutterParams` whose every obstacle moves at constant velocity, in a
    uniformly random horizontal direction, at a speed uniform in ``speed = 0.2–1.0 m/s``
    (at most half the UAV's per-axis limit)."""

    family = "dynamic"
    CHECKS = ClutterParams.CHECKS | {"speed": span(0.0)}
    UNITS = ClutterParams.UNITS | {"speed": "m/s"}

    speed: tuple[float, float] = (0.2, 1.0)


@dataclasses.dataclass(frozen=True)
class MovingParams(FamilyParams):
    """Common to ``crossing``, ``head_on`` and ``overtake``: a number of moving obstacles uniform in
    the integers ``count`` (whose upper end must not exceed ``max_obstacles``), each with a radius
    uniform in ``radius`` [m] and a speed uniform in ``speed`` [m/s]. ``goal_margin`` defaults to
    0.25 m: these obstacles cross or run along the line and are gone from the goal's neighbourhood
    long before the UAV arrives, and a larger margin would push them off their courses."""

    CHECKS = FamilyParams.CHECKS | {
        "count": span(1, integer=True),
        "radius": span(0.0, lo_open=True),
        "speed": span(0.0),
    }
    UNITS = FamilyParams.UNITS | {"count": "", "radius": "m", "speed": "m/s"}

    count: tuple[int, int] = (1, 2)
    radius: tuple[float, float] = (0.5, 1.0)
    speed: tuple[float, float] = (0.5, 1.5)
    goal_margin: float = 0.25

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
        "meet": span(0.0, 1.0),
        "timing": span(),
        "uav_speed": number(0.0, lo_open=True),
    }
    UNITS = MovingParams.UNITS | {"meet": "", "timing": "s", "uav_speed": "m/s"}

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
    CHECKS = MovingParams.CHECKS | {"along": span(0.0, 1.0), "offset": number(0.0)}
    UNITS = MovingParams.UNITS | {"along": "", "offset": "m"}

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
    CHECKS = MovingParams.CHECKS | {"behind": span(0.0, lo_open=True), "offset": number(0.0)}
    UNITS = MovingParams.UNITS | {"behind": "m", "offset": "m"}

    max_obstacles: int = 2
    speed: tuple[float, float] = (3.0, 5.0)
    behind: tuple[float, float] = (4.0, 10.0)
    offset: float = 0.5



# --------------------------------------------------------------------------------------------
# builders: (draws, params, L) -> Layout in the local frame
# --------------------------------------------------------------------------------------------


def _paper_static(d: Draws, p: PaperStaticParams, length: Array) -> tuple[Layout, int]:
    ring = cup(0.5 * length, jnp.zeros_like(length), p.cup_radius, p.radius)
    return ring._replace(xy=ring.xy + d.uniform((-p.jitter, p.jitter), ring.xy.shape)), 0


def _paper_dynamic(d: Draws, p: PaperDynamicParams, length: Array) -> tuple[Layout, int]:
    field = scatter(d, p.max_obstacles, p.count, length, p.width, p.radius)
    return with_motion(field, d, p.speed, jnp.arange(p.max_obstacles) < p.n_moving), 0


def _trap_on_line(d: Draws, p: TrapParams, length: Array, x: Array, y: Array) -> Layout:
    return static(jnp.stack([x, y])[None], d.uniform(p.radius, (1,)))


def _trap_concave(d: Draws, p: TrapParams, length: Array, x: Array, y: Array) -> Layout:
    cup_radius = d.uniform(p.cup_radius)
    return cup(x, y, cup_radius, p.cup_fill * cup_radius * math.sin(0.5 * math.pi / (CUP_SIZE - 1)))


def _trap_narrow_gap(d: Draws, p: TrapParams, length: Array, x: Array, y: Array) -> Layout:
    radius = d.uniform(p.radius)
    half = 0.5 * (2.0 * p.r_uav + d.uniform(p.gap_slack)) + radius
    return static(jnp.stack([jnp.stack([x, y + half]), jnp.stack([x, y - half])]), jnp.stack([radius, radius]))


def _trap_gnron(d: Draws, p: TrapParams, length: Array, x: Array, y: Array) -> Layout:
    del x, y  # placed relative to the goal
    radius = d.uniform(p.radius, (1,))
    reach = radius + p.r_uav + d.uniform(p.goal_clearance, (1,))
    goal = jnp.stack([length, jnp.zeros_like(length)])
    return static(goal + reach[:, None] * d.directions(1), radius)


_TRAP_BUILDERS: Mapping[str, Callable[..., Layout]] = {
    "on_line": _trap_on_line,
    "concave": _trap_concave,
    "narrow_gap": _trap_narrow_gap,
    "gnron": _trap_gnron,
}


def _trap(d: Draws, p: TrapParams, length: Array) -> tuple[Layout, Array]:
    """Every kind is built (they are tiny) in the order of ``TRAP_KINDS`` so that a kind's geometry
    in a field does not depend on which other kinds are selected; one selected kind is kept, and its
    index in ``TRAP_KINDS`` is the field's kind."""
    pick = d.integers(0, len(p.kinds) - 1)
    x = d.uniform(p.along) * length
    y = d.uniform((-p.offset, p.offset))
    layouts = {k: fit(_TRAP_BUILDERS[k](d, p, length, x, y), CUP_SIZE) for k in TRAP_KINDS}
    kind = jnp.asarray([TRAP_KINDS.index(k) for k in p.kinds])[pick]
    return jax.tree.map(lambda *rows: jnp.stack(rows)[pick], *(layouts[k] for k in p.kinds)), kind


def _forest(d: Draws, p: ClutterParams, length: Array) -> Layout:
    count = jnp.minimum(jnp.round(p.density * length * p.width / 100.0), p.max_obstacles)
    return scatter(d, p.max_obstacles, count, length, p.width, p.radius)


def _clutter(d: Draws, p: ClutterParams, length: Array) -> tuple[Layout, int]:
    return _forest(d, p, length), 0


def _dynamic(d: Draws, p: DynamicParams, length: Array) -> tuple[Layout, int]:
    field = _forest(d, p, length)
    return with_motion(field, d, p.speed, field.valid), 0


def _movers(d: Draws, p: MovingParams, place: Callable[[Array], tuple[Array, Array]]) -> Layout:
    """``max_obstacles`` rows, the first ``count`` valid; ``place(speed)`` returns the centres and
    velocities (n, 2) given each row's speed (n,)."""
    n = p.max_obstacles
    count = d.integers(*p.count)
    radius = d.uniform(p.radius, (n,))
    xy, vxy = place(d.uniform(p.speed, (n,)))
    return Layout(xy, vxy, radius, jnp.arange(n) < count)


def _crossing(d: Draws, p: CrossingParams, length: Array) -> tuple[Layout, int]:
    def place(speed: Array) -> tuple[Array, Array]:
        x = d.uniform(p.meet, speed.shape) * length
        t_meet = x / p.uav_speed + d.uniform(p.timing, speed.shape)
        vy = d.signs(speed.shape) * speed
        return jnp.stack([x, -vy * t_meet], -1), jnp.stack([jnp.zeros_like(vy), vy], -1)

    return _movers(d, p, place), 0


def _along_line(d: Draws, p: HeadOnParams | OvertakeParams, x_span: tuple, sign: float) -> Layout:
    """Movers starting at x uniform in ``x_span`` (lateral offset ±``p.offset``) and flying parallel
    to the line, toward the goal (``sign = +1``) or toward the start (``sign = -1``)."""

    def place(speed: Array) -> tuple[Array, Array]:
        xy = jnp.stack([d.uniform(x_span, speed.shape), d.uniform((-p.offset, p.offset), speed.shape)], -1)
        return xy, jnp.stack([sign * speed, jnp.zeros_like(speed)], -1)

    return _movers(d, p, place)


def _head_on(d: Draws, p: HeadOnParams, length: Array) -> tuple[Layout, int]:
    return _along_line(d, p, (p.along[0] * length, p.along[1] * length), -1.0), 0


def _overtake(d: Draws, p: OvertakeParams, length: Array) -> tuple[Layout, int]:
    return _along_line(d, p, (-p.behind[1], -p.behind[0]), 1.0), 0


register_family(PaperStaticParams, _paper_static,
                description="the paper's scenario 1: a closed cup of 5 cylinders across the start-goal line")
register_family(PaperDynamicParams, _paper_dynamic,
                description="the paper's scenario 2: a 70 m run through 14 cylinders, 4 of them drifting")
register_family(TrapParams, _trap, TRAP_KINDS, defining="concave",
                description="one local-minimum trap per field: obstacle on the line, concave cup, narrow gap, "
                            "goal near an obstacle")
register_family(ClutterParams, _clutter, description="a static forest of cylinders in a 12 m corridor")
register_family(CrossingParams, _crossing, description="1-3 obstacles crossing the path perpendicularly")
register_family(HeadOnParams, _head_on, description="1-2 obstacles flying toward the UAV along its path")
register_family(OvertakeParams, _overtake, description="1-2 obstacles overtaking the UAV from behind at 1.5-2.5 v_max")
register_family(DynamicParams, _dynamic, description="clutter whose every obstacle drifts in a random direction")

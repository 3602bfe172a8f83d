r"""Solvability oracle: could any planner fly a field from start to goal without a collision?

A planner that stalls in a field where no collision-free path exists is not at fault: reports can
give rates among the fields this oracle calls solvable. :func:`solvable` answers for a batch of
fields (a :class:`~jaxapf.datatypes.Scenario` whose leaves have leading batch axes, as
:func:`~jaxapf.scenarios.make_scenarios` returns), on the host, in numpy/scipy, one field at a time.
It answers a relaxation of the question: "unsolvable" is a proof (no collision-free flight exists),
"solvable" may be optimistic (the acceleration limit is ignored). Static fields are an
8-connectivity test on a rasterised plane, moving fields a space–time reachability on a grid;
docs/scenarios.md ("The solvability oracle") states the definition, its assumptions and why each
answer means what it says. Before either search, a certificate answers most solvable fields at a
fraction of its cost (a free path of whole blocks of cells; a flight through the reachable sets): it
can only find what the search would, so the answers are the search's (``certify=False`` runs the
search alone, the reference the tests hold the certificates to).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Iterable, Iterator

import numpy as np
from scipy import ndimage
from scipy.sparse.csgraph import connected_components

from ..validation import check_range

__all__ = ["solvable", "solvable_field", "reach_cell", "RESOLUTION", "REACH_RESOLUTION", "MARGIN",
           "CELL_STEPS"]

#: Default grid cell [m] of the connectivity test of static fields.
RESOLUTION = 0.025
#: Default (finest) grid cell [m] of the space–time reachability.
REACH_RESOLUTION = 0.1
#: Default growth [m] of the start–goal bounding box that the search covers.
MARGIN = 5.0
#: Default budget of (grid cells) × (time steps) of the space–time reachability (sets its coarsening).
CELL_STEPS = 1.5e8

_EIGHT = np.ones((3, 3), bool)


@dataclasses.dataclass(frozen=True)
class _Field:
    """One field's valid obstacles, float64: start, goal (3,); position, velocity (n, 3); radius,
    cylinder (n,)."""

    start: np.ndarray
    goal: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    radius: np.ndarray
    cylinder: np.ndarray

    def moving(self) -> np.ndarray:
        """(n,) True where the obstacle moves in a way the plane can see (a cylinder's vertical
        velocity changes nothing)."""
        v = np.where(self.cylinder[:, None], self.velocity * np.array([1.0, 1.0, 0.0]), self.velocity)
        return np.any(v != 0.0, axis=1)

    def clearance(self, p: np.ndarray, t: float, which: np.ndarray) -> np.ndarray:
        """Distance (n,) from ``p`` to each obstacle's surface at time ``t``, ``|P(p - p_o(t))| - rho``
        (the UAV's clearance plus ``r_uav``); +inf where not ``which``."""
        rel = p - (self.position + self.velocity * t)
        rel = np.where(self.cylinder[:, None], rel * np.array([1.0, 1.0, 0.0]), rel)
        return np.where(which, np.linalg.norm(rel, axis=1) - self.radius, np.inf)


class _Grid:
    """Square cells of side ``h`` covering the box ``lo … hi`` (2,), plus one ring of cells on every
    side (the *ring*: space outside the box), plus ``pad`` more cells on every side that are never
    free (room for stamping obstacles without bounds checks). Row ``i`` is y, column ``j`` is x;
    cell centres ``x[j]``, ``y[i]``."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, h: float, pad: int = 0) -> None:
        n = np.maximum(np.ceil((hi - lo) / h - 1e-9).astype(int), 1) + 2 + 2 * pad
        self.h, self.pad = h, pad
        self.origin = lo - (1 + pad) * h  # lower-left corner of cell (0, 0)
        self.nx, self.ny = int(n[0]), int(n[1])
        self.x = self.origin[0] + (np.arange(self.nx) + 0.5) * h
        self.y = self.origin[1] + (np.arange(self.ny) + 0.5) * h

    @property
    def shape(self) -> tuple[int, int]:
        return self.ny, self.nx

    @property
    def extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners (2,) of the box and its ring (the pad excluded)."""
        lo = self.origin + self.pad * self.h
        return lo, lo + self.h * np.array([self.nx - 2 * self.pad, self.ny - 2 * self.pad])

    def searched(self) -> np.ndarray:
        """(ny, nx) True on the box and its ring, False on the pad."""
        inside = np.zeros(self.shape, bool)
        p = self.pad
        inside[p:self.ny - p, p:self.nx - p] = True
        return inside

    def ring(self) -> np.ndarray:
        """(ny, nx) True on the ring."""
        ring = self.searched()
        p = self.pad + 1
        ring[p:self.ny - p, p:self.nx - p] = False
        return ring

    def cell(self, xy: np.ndarray) -> tuple[int, int]:
        """(row, column) of the cell holding ``xy`` (clipped into the grid)."""
        j, i = (math.floor(v) for v in (xy - self.origin) / self.h)
        return min(max(i, 0), self.ny - 1), min(max(j, 0), self.nx - 1)

    def window(self, centre: np.ndarray, radius: float) -> tuple[slice, slice]:
        """Rows and columns of the cells whose centres may lie within ``radius`` of ``centre``."""
        lo = np.floor((centre - radius - self.origin) / self.h - 0.5).astype(int)
        hi = np.ceil((centre + radius - self.origin) / self.h - 0.5).astype(int) + 1
        clip = lambda i, n: min(max(int(i), 0), n)  # noqa: E731
        return (slice(clip(lo[1], self.ny), clip(hi[1], self.ny)), slice(clip(lo[0], self.nx), clip(hi[0], self.nx)))

    def within(self, centre: np.ndarray, radius: float) -> tuple[tuple[slice, slice], np.ndarray]:
        """A window and the mask of its cells whose centres lie within ``radius`` of ``centre``."""
        rows, cols = self.window(centre, radius)
        d2 = (self.y[rows, None] - centre[1]) ** 2 + (self.x[None, cols] - centre[0]) ** 2
        return (rows, cols), d2 <= radius * radius

    def paint(self, blocked: np.ndarray, centres: np.ndarray, r2: np.ndarray) -> None:
        """Mark in ``blocked`` every cell whose centre lies strictly inside a disc (centres (m, 2),
        squared radii (m,); discs with ``r2 <= 0`` are absent)."""
        for centre, q in zip(centres, r2):
            if q > 0:
                rows, cols = self.window(centre, math.sqrt(q))
                d2 = (self.y[rows, None] - centre[1]) ** 2 + (self.x[None, cols] - centre[0]) ** 2
                blocked[rows, cols] |= d2 < q

    def cover(self, centres: np.ndarray, r2: np.ndarray, half: int) -> np.ndarray:
        """Flat indices of the cells whose centres lie strictly inside a disc, all discs at once
        (radii below ``half - 1`` cells, centres within the box and ring grown by ``pad - half``
        cells)."""
        off = np.arange(-half, half + 1)
        cell = np.floor((centres - self.origin) / self.h).astype(np.intp)
        cj, ci = cell[:, :1] + off, cell[:, 1:] + off
        dx2 = (self.x[cj] - centres[:, :1]) ** 2
        dy2 = (self.y[ci] - centres[:, 1:]) ** 2
        hit = dy2[:, :, None] + dx2[:, None, :] < r2[:, None, None]
        return (ci[:, :, None] * self.nx + cj[:, None, :])[hit]


def _blocking_r2(f: _Field, which: np.ndarray, t: float, height: float, reach: np.ndarray) -> np.ndarray:
    """Squared radius (n,) of the disc of the plane ``z = height`` that obstacle ``i`` blocks at time
    ``t`` (``reach = rho + r_uav - slack``); ``<= 0`` where absent or not ``which``."""
    dz = np.where(f.cylinder, 0.0, height - (f.position[:, 2] + f.velocity[:, 2] * t))
    r2 = np.where(reach > 0, reach * reach, 0.0) - dz * dz
    return np.where(which & (reach > 0), r2, 0.0)


def _relevant(centres: np.ndarray, radii: np.ndarray, lo: np.ndarray, hi: np.ndarray, tol: float) -> np.ndarray:
    """(n,) True for the discs (centres (n, 2), radii (n,) > 0) that touch the box ``lo … hi``, and
    for every disc joined to one of them by a chain of discs less than ``tol`` apart."""
    touch = np.all(centres + radii[:, None] > lo, 1) & np.all(centres - radii[:, None] < hi, 1)
    if not touch.any() or touch.all():
        return touch
    near = np.hypot(*(centres[:, None, :] - centres[None, :, :]).transpose(2, 0, 1)) < radii[:, None] + radii + tol
    _, group = connected_components(near, directed=False)
    return np.isin(group, group[touch])


def _static_discs(f: _Field, r_uav: float, h: float, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Which obstacles (n,) the static test rasterises, and their blocking squared radii (n,) at
    cell ``h``: those whose blocked disc touches the start–goal box grown by ``margin``, or is joined
    to one by a chain of discs (docs/scenarios.md)."""
    r2 = _blocking_r2(f, np.ones(f.radius.shape, bool), 0.0, f.start[2], f.radius + r_uav - h / math.sqrt(2))
    lo = np.minimum(f.start[:2], f.goal[:2]) - margin
    hi = np.maximum(f.start[:2], f.goal[:2]) + margin
    keep = r2 > 0
    keep[keep] = _relevant(f.position[keep, :2], np.sqrt(r2[keep]), lo, hi, 2.0 * h)
    return keep, r2


def _chebyshev_sum(p: np.ndarray, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """``|p - start|_inf + |p - goal|_inf`` over the last axis (2) of ``p`` (world xy)."""
    return np.abs(p - start).max(-1) + np.abs(p - goal).max(-1)


@dataclasses.dataclass(frozen=True)
class _Frame:
    """The static test's grid in the frame of the start–goal line (x along it from the start, y to its left):
    the discs it rasterises (``centres`` (m, 2), ``r2`` (m,)), the goal (2,), the line's direction ``u``
    (world), the region's ``budget`` and whether its box left every disc uncut (:func:`_static_frame`)."""

    grid: _Grid
    centres: np.ndarray
    r2: np.ndarray
    goal: np.ndarray
    u: np.ndarray
    budget: float
    uncut: bool


def _static_frame(f: _Field, keep: np.ndarray, r2: np.ndarray, r_goal: float, h: float, travel: float) -> _Frame:
    """The grid of :func:`_connected`: the box holding start, goal and the ``keep`` discs, cut to the ellipse
    that holds the region a UAV flying at most ``travel`` [m] per axis could visit (docs/scenarios.md)."""
    along = f.goal[:2] - f.start[:2]
    length = float(np.hypot(*along))
    u = along / length if length > 0 else np.array([1.0, 0.0])
    rot = np.array([[u[0], u[1]], [-u[1], u[0]]])  # world xy -> local (along, left)
    centres, r2 = (f.position[keep, :2] - f.start[:2]) @ rot.T, r2[keep]
    goal, reach = np.array([length, 0.0]), np.sqrt(r2)
    lo = np.min([np.zeros(2), goal, *(centres - reach[:, None])], 0)
    hi = np.max([np.zeros(2), goal, *(centres + reach[:, None])], 0)
    # the region: |p - s|_inf + |p - g|_inf <= budget lies in the ellipse |p - s| + |p - g| <= sqrt 2 budget
    budget = travel + r_goal + h
    axis = math.sqrt(2.0) * budget
    cut_lo = np.maximum(lo, [0.5 * (length - axis), -0.5 * math.sqrt(max(axis * axis - length * length, 0.0))])
    cut_hi = np.minimum(hi, [0.5 * (length + axis), 0.5 * math.sqrt(max(axis * axis - length * length, 0.0))])
    uncut = bool(np.all(cut_lo == lo) and np.all(cut_hi == hi))  # every disc inside the box: the ring is free
    return _Frame(_Grid(cut_lo, np.maximum(cut_hi, cut_lo), h), centres, r2, goal, u, budget, uncut)


def _connected(f: _Field, keep: np.ndarray, r2: np.ndarray, r_goal: float, h: float, travel: float,
               certify: bool = True) -> bool:
    """Whether start and goal cells share an 8-connected component of free cells (static fields),
    on a grid of ``h`` in the frame of the start–goal line (rotations do not change connectivity),
    within the region a UAV that flies at most ``travel`` [m] per axis could visit
    (docs/scenarios.md)."""
    frame = _static_frame(f, keep, r2, r_goal, h, travel)
    grid, centres, r2, goal, u, budget = frame.grid, frame.centres, frame.r2, frame.goal, frame.u, frame.budget
    to_world = lambda x, y: f.start[:2] + x[..., None] * u + y[..., None] * np.array([-u[1], u[0]])  # noqa: E731
    corners = to_world(np.array([grid.x[0], grid.x[-1], grid.x[0], grid.x[-1]]),
                       np.array([grid.y[0], grid.y[0], grid.y[-1], grid.y[-1]]))
    clipped = np.any(_chebyshev_sum(corners, f.start[:2], f.goal[:2]) > budget)  # the region is convex
    window, near = grid.within(goal, r_goal + h / math.sqrt(2))
    start = grid.cell(np.zeros(2))
    inside = (lambda x, y: _chebyshev_sum(to_world(x, y), f.start[:2], f.goal[:2]) <= budget * (1.0 - 1e-12)
              ) if clipped else None
    if certify and _coarsely_connected(grid, centres, r2, start, window, near, inside, frame.uncut and not clipped):
        return True
    blocked = np.zeros(grid.shape, bool)
    grid.paint(blocked, centres, r2)
    if clipped:
        blocked |= _chebyshev_sum(to_world(grid.x[None, :], grid.y[:, None]), f.start[:2], f.goal[:2]) > budget
    labels, _ = ndimage.label(~blocked, structure=_EIGHT)
    mine = labels[start]
    return bool(mine > 0 and np.any(labels[window][near] == mine))


#: Fine cells per side of a block of the static test's certificate (:func:`_coarsely_connected`).
_BLOCK = 4


def _coarsely_connected(grid: _Grid, centres: np.ndarray, r2: np.ndarray, start: tuple[int, int],
                        window: tuple[slice, slice], near: np.ndarray, inside: Any, ring_free: bool) -> bool:
    """A certificate of the static test: whether the start's cell and a goal cell are joined by blocks of
    ``_BLOCK`` × ``_BLOCK`` cells (fewer at the grid's far edges) that are wholly free (no disc reaches the
    rectangle of their cells' centres, with a margin for rounding; ``inside(x, y)``, the region's test where it
    cuts the grid, holds at its corners: the region is convex)
    and 8-connected, or (``ring_free``: no disc reaches the grid's outermost ring of cells, nor does the region
    cut it) both joined to blocks on the grid's edge, which the ring joins. Every cell of such a block is free
    and 8-adjacent blocks touch, so the fine grid's components join them too: the search would answer
    solvable. A sixteenth of the cells to label; ``False``
    asks the search itself."""
    b = _BLOCK
    ny, nx = -(-grid.ny // b), -(-grid.nx // b)  # the last row and column of blocks may hold fewer cells
    xa, xb = grid.x[0::b], grid.x[np.minimum(np.arange(nx) * b + b - 1, grid.nx - 1)]  # first and last centres
    ya, yb = grid.y[0::b], grid.y[np.minimum(np.arange(ny) * b + b - 1, grid.ny - 1)]
    margin = 1e-9 * (1.0 + np.abs(centres).max(initial=0.0))
    clear = np.ones((ny, nx), bool)
    side = b * grid.h
    for (cx, cy), q in zip(centres, r2):
        if q <= 0:
            continue
        reach = math.sqrt(q) + margin
        (j0, i0), (j1, i1) = ((np.array([cx, cy]) + sign * reach - grid.origin) // side for sign in (-1, 1))
        j0, j1, i0, i1 = max(int(j0) - 1, 0), min(int(j1) + 2, nx), max(int(i0) - 1, 0), min(int(i1) + 2, ny)
        if j0 >= j1 or i0 >= i1:
            continue
        dx = np.maximum(np.maximum(xa[j0:j1] - cx, cx - xb[j0:j1]), 0.0)
        dy = np.maximum(np.maximum(ya[i0:i1] - cy, cy - yb[i0:i1]), 0.0)
        clear[i0:i1, j0:j1] &= dy[:, None] ** 2 + dx[None, :] ** 2 >= reach * reach
    for x, y in ((xa, ya), (xb, ya), (xa, yb), (xb, yb)) if inside is not None else ():
        clear &= inside(x[None, :], y[:, None])
    si, sj = start[0] // b, start[1] // b
    if not clear[si, sj]:
        return False
    rows, cols = np.nonzero(near)  # the goal cells, as blocks
    rows, cols = (rows + window[0].start) // b, (cols + window[1].start) // b
    rows, cols = rows[clear[rows, cols]], cols[clear[rows, cols]]
    if rows.size == 0:
        return False
    labels, _ = ndimage.label(clear, structure=_EIGHT)
    mine, goals = labels[si, sj], labels[rows, cols]
    if np.any(goals == mine):
        return True
    if not ring_free:
        return False
    edge = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    return bool(np.isin(mine, edge) and np.any(np.isin(goals, edge[edge > 0])))


def _presence(f: _Field, lo: np.ndarray, hi: np.ndarray, height: float,
              reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Times ``[t_in, t_out]`` (each (n,)) outside which obstacle ``i``'s blocked disc cannot touch
    the box ``lo … hi``: when its centre is outside the box grown by its reach on x or on y, or
    (a sphere) farther than its reach from the plane. An interval that is empty comes back as
    ``(inf, -inf)``."""
    cyl = f.cylinder  # ignores z: held in the plane
    centre = np.concatenate([f.position[:, :2], np.where(cyl, height, f.position[:, 2])[:, None]], 1)
    speed = np.concatenate([f.velocity[:, :2], np.where(cyl, 0.0, f.velocity[:, 2])[:, None]], 1)
    low = np.stack([lo[0] - reach, lo[1] - reach, height - reach], 1)
    high = np.stack([hi[0] + reach, hi[1] + reach, height + reach], 1)
    still = speed == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (low - centre) / speed, (high - centre) / speed
    inside = (centre >= low) & (centre <= high)
    t0 = np.where(still, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb)).max(1)
    t1 = np.where(still, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb)).min(1)
    never = (t0 > t1) | (reach <= 0)
    return np.where(never, np.inf, t0), np.where(never, -np.inf, t1)


def _reachable(f: _Field, movers: np.ndarray, lo: np.ndarray, hi: np.ndarray, r_uav: float, v_max: float,
               t_max: float, r_goal: float, h: float, certify: bool = True) -> bool:
    """Space–time reachability on a grid of ``h`` in world axes over the box ``lo … hi``
    (docs/scenarios.md); ``movers`` (n,) marks the obstacles to move, the others are painted once."""
    height = f.start[2]
    slack = h / math.sqrt(2)
    reach = f.radius + r_uav - slack
    half = int(math.ceil(float(np.max(reach[movers], initial=0.0)) / h)) + 2  # cells a mover's disc spans
    grid = _Grid(lo, hi, h, pad=2 * half)

    blocked = np.zeros(grid.shape, bool)
    grid.paint(blocked, f.position[:, :2], _blocking_r2(f, ~movers, 0.0, height, reach))
    free = grid.searched() & (~blocked | grid.ring())

    t_in, t_out = _presence(f, *grid.extent, height, reach)
    t_in, t_out = t_in[movers], t_out[movers]
    t_quiet = float(np.max(t_out, initial=-np.inf))  # no mover touches the grid after t_quiet
    t_first = float(np.min(t_in, initial=np.inf))  # nor before t_first
    moving = t_first <= t_quiet
    m = dataclasses.replace(f, position=f.position[movers], velocity=f.velocity[movers], radius=f.radius[movers],
                            cylinder=f.cylinder[movers])
    m_reach = reach[movers]
    climbing = bool(np.any(~m.cylinder & (m.velocity[:, 2] != 0)))
    m_r2 = _blocking_r2(m, np.ones(m_reach.shape, bool), 0.0, height, m_reach)

    goal_window, goal_near = grid.within(f.goal[:2], r_goal + slack + math.sqrt(2) * h)
    dt = h / v_max
    steps = int(math.floor(t_max / dt + 1e-9))

    si, sj = grid.cell(f.start[:2])
    goal_cells = np.zeros(grid.shape, bool)
    goal_cells[goal_window] = goal_near
    discs = _mover_discs(m, moving, t_first, t_quiet, t_in, t_out, climbing, height, m_reach, m_r2,
                         np.arange(steps + 1) * dt)
    if certify and _flown(_moving_paths(f, grid, (si, sj), steps), free, goal_cells, discs, grid):
        return True
    reached = np.zeros(grid.shape, bool)
    flat = reached.reshape(-1)
    reached[si, sj] = True
    if np.any(reached[goal_window][goal_near]):
        return True
    r0, r1, c0, c1 = si, si + 1, sj, sj + 1  # a box holding the reachable set
    count = 1
    for k in range(1, steps + 1):
        t = k * dt
        r0, r1, c0, c1 = max(r0 - 1, 0), min(r1 + 1, grid.ny), max(c0 - 1, 0), min(c1 + 1, grid.nx)
        old = reached[r0:r1, c0:c1]
        rows = old.copy()
        rows[1:] |= old[:-1]
        rows[:-1] |= old[1:]
        new = rows.copy()
        new[:, 1:] |= rows[:, :-1]
        new[:, :-1] |= rows[:, 1:]
        new &= free[r0:r1, c0:c1]
        reached[r0:r1, c0:c1] = new
        if moving and t_first <= t <= t_quiet:
            centres, r2 = _mover_discs(m, moving, t_first, t_quiet, t_in, t_out, climbing, height, m_reach, m_r2, t)
            on = r2 > 0
            flat[grid.cover(centres[on], r2[on], half)] = False
        if reached[goal_window][goal_near].any():
            return True
        if k % 8 == 0:  # shrink the box to the reachable set; stop if it is empty or has stopped growing
            now = reached[r0:r1, c0:c1]
            any_row = np.flatnonzero(now.any(axis=1))
            if any_row.size == 0:
                return False  # caught: no cell is reachable any more
            any_col = np.flatnonzero(now.any(axis=0))
            r0, r1, c0, c1 = r0 + any_row[0], r0 + any_row[-1] + 1, c0 + any_col[0], c0 + any_col[-1] + 1
            grown = int(np.count_nonzero(now))
            if grown == count and (k - 8) * dt > t_quiet:  # static for 8 steps, the set only grows: stuck
                return False
            count = grown
    return False


def _mover_discs(m: _Field, moving: bool, t_first: float, t_quiet: float, t_in: np.ndarray, t_out: np.ndarray,
                 climbing: bool, height: float, reach: np.ndarray, r2_still: np.ndarray,
                 t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres (..., n, 2) and squared radii (..., n) of the discs the movers block at the times ``t`` (any
    shape; a radius <= 0: no disc, as outside the movers' presence in the grid)."""
    t = np.asarray(t, np.float64)[..., None]
    active = (t_in <= t) & (t <= t_out) & ((t_first <= t) & (t <= t_quiet) if moving else False)
    if climbing:
        dz = np.where(m.cylinder, 0.0, height - (m.position[:, 2] + m.velocity[:, 2] * t))
        r2 = np.where(active & (reach > 0), np.where(reach > 0, reach * reach, 0.0) - dz * dz, 0.0)
    else:
        r2 = np.where(active, r2_still, 0.0)
    return m.position[:, :2] + m.velocity[:, :2] * t[..., None], r2


#: The candidate flights of the reachability's certificate (:func:`_moving_paths`): a waypoint this far [m] to
#: either side of the start–goal line, at these fractions of the way, and these waits [steps] before the start.
_SIDESTEPS = (1.0, 2.0, 3.5, 5.0)
_WAYPOINTS_AT = (0.1, 0.5)
_WAITS = (10, 25, 50)


def _line(a: tuple[int, int], b: tuple[int, int]) -> np.ndarray:
    """Cells (n, 2) of the straight line from ``a`` (excluded) to ``b`` in n = max(|Δrow|, |Δcolumn|) steps of at
    most one cell per axis (8-connected, and as fast as the per-axis limit allows)."""
    d = np.subtract(b, a)
    n = int(np.abs(d).max(initial=0))
    return np.asarray(a) + np.rint(np.arange(1, n + 1)[:, None] * d / max(n, 1)).astype(int)


def _moving_paths(f: _Field, grid: _Grid, start: tuple[int, int], steps: int) -> Iterator[np.ndarray]:
    """Candidate flights on ``grid``, each the (row, column) of its cell at steps 0, 1, ... (at most ``steps``),
    made as they are asked for: straight to the goal, through a waypoint beside the start–goal line, after a
    wait."""
    goal = grid.cell(f.goal[:2])
    along = f.goal[:2] - f.start[:2]
    side = np.array([-along[1], along[0]]) / max(float(np.hypot(*along)), 1e-9)
    plans = [(0, [])] + [(0, [f.start[:2] + at * along + sign * d * side]) for at in _WAYPOINTS_AT
                         for d in _SIDESTEPS for sign in (1.0, -1.0)] + [(w, []) for w in _WAITS]
    for wait, waypoints in plans:
        legs, here = [np.repeat([start], wait + 1, axis=0)], start
        for target in [grid.cell(w) for w in waypoints] + [goal]:
            legs.append(_line(here, target))
            here = target
        yield np.concatenate(legs)[:steps + 1]


def _flown(paths: Iterable[np.ndarray], free: np.ndarray, goal_cells: np.ndarray, discs: tuple[np.ndarray, np.ndarray],
           grid: _Grid) -> bool:
    """Whether one of ``paths`` (cells at steps 0, 1, ...) is a flight of the space–time reachability: every
    cell after the start free of static obstacles and of the movers' discs at its step (``discs``: centres
    (K, n, 2) and squared radii (K, n) at steps 0 … K-1, the search's own arithmetic), until one is a goal
    cell. Each such flight lies in the reachable sets (R_k holds its k-th cell), so the search would answer
    solvable too: a certificate, never another answer."""
    centres, r2 = discs
    for path in paths:
        rows, cols = path[:, 0], path[:, 1]
        k = len(path)
        dx2 = (grid.x[cols][:, None] - centres[:k, :, 0]) ** 2
        dy2 = (grid.y[rows][:, None] - centres[:k, :, 1]) ** 2
        ok = free[rows, cols] & ~np.any(dy2 + dx2 < r2[:k], axis=1)
        ok[0] = True  # R_0 is the start's cell, whatever lies there
        goal = np.flatnonzero(goal_cells[rows, cols][1:])
        if goal.size and ok[:goal[0] + 2].all():
            return True
    return False


def reach_cell(area: float, *, v_max: float, t_max: float, resolution: float = REACH_RESOLUTION,
               cell_steps: float = CELL_STEPS) -> float:
    """The grid cell [m] of the space–time reachability over a box of ``area`` [m²]:
    ``max(resolution, (area · t_max · v_max / cell_steps)^(1/3))`` (docs/scenarios.md)."""
    return max(float(resolution), (float(area) * t_max * v_max / cell_steps) ** (1.0 / 3.0))


def _field(start: Any, goal: Any, position: Any, velocity: Any, radius: Any, cylinder: Any, valid: Any) -> _Field:
    """The valid obstacles of one field, in float64."""
    radius = np.asarray(radius, np.float64).reshape(-1)
    valid = np.ones(radius.shape, bool) if valid is None else np.asarray(valid, bool).reshape(-1)
    return _Field(start=np.asarray(start, np.float64), goal=np.asarray(goal, np.float64),
                  position=np.asarray(position, np.float64).reshape(-1, 3)[valid],
                  velocity=np.asarray(velocity, np.float64).reshape(-1, 3)[valid],
                  radius=radius[valid], cylinder=np.asarray(cylinder, bool).reshape(-1)[valid])


def solvable_field(start: Any, goal: Any, position: Any, velocity: Any, radius: Any, cylinder: Any,
                   valid: Any = None, *, r_uav: float, v_max: float, t_max: float, r_goal: float = 0.5,
                   resolution: float = RESOLUTION, reach_resolution: float = REACH_RESOLUTION,
                   margin: float = MARGIN, cell_steps: float = CELL_STEPS, certify: bool = True) -> bool:
    """Whether one field is solvable (docs/scenarios.md). Arrays as in
    :class:`~jaxapf.datatypes.Scenario` and :class:`~jaxapf.datatypes.Obstacles` without batch axes
    (``valid`` defaults to all True); keyword arguments as for :func:`solvable`, unchecked."""
    f = _field(start, goal, position, velocity, radius, cylinder, valid)
    statics = ~f.moving()
    if np.any(f.clearance(f.start, 0.0, np.ones(statics.shape, bool)) < r_uav):
        return False
    if np.any(f.clearance(f.goal, 0.0, statics) < r_uav):
        return False
    if np.abs(f.goal - f.start).max() - r_goal > v_max * t_max:
        return False  # too far to fly even without obstacles
    if np.all(statics):
        keep, r2 = _static_discs(f, r_uav, resolution, margin)
        return _connected(f, keep, r2, r_goal, resolution, v_max * t_max, certify)
    lo = np.minimum(f.start[:2], f.goal[:2]) - margin
    hi = np.maximum(f.start[:2], f.goal[:2]) + margin
    h = reach_cell(float(np.prod(hi - lo)), v_max=v_max, t_max=t_max, resolution=reach_resolution,
                   cell_steps=cell_steps)
    return _reachable(f, ~statics, lo, hi, r_uav, v_max, t_max, r_goal, h, certify)


def solvable(scenarios: Any, *, r_uav: float, v_max: float, t_max: float, r_goal: float = 0.5,
             resolution: float = RESOLUTION, reach_resolution: float = REACH_RESOLUTION,
             margin: float = MARGIN, cell_steps: float = CELL_STEPS, certify: bool = True) -> np.ndarray:
    """Whether each field of a batch is solvable: a bool array of the batch's shape.

    Args:
      scenarios: a :class:`~jaxapf.datatypes.Scenario` (JAX or numpy leaves) with any leading batch
        axes (none: one field, a 0-d result), as :func:`~jaxapf.scenarios.make_scenarios` returns.
      r_uav: UAV radius [m] >= 0 (``VehicleConfig.r_uav``).
      v_max: per-axis velocity limit [m/s] > 0 (``VehicleConfig.v_max``).
      t_max: episode length [s] > 0 (``EpisodeConfig.t_max``, or the family's recommended ``t_max``).
      r_goal: goal tolerance [m] >= 0 (``EpisodeConfig.r_goal``).
      resolution: grid cell [m] > 0 of the connectivity test of static fields.
      reach_resolution: finest grid cell [m] > 0 of the space–time reachability (coarsened for
        large boxes, see :func:`reach_cell`).
      margin: growth [m] >= 0 of the start–goal bounding box that the search covers.
      cell_steps: budget > 0 of (grid cells) × (time steps) of the space–time reachability.
      certify: try the certificates first (the same answers, sooner); False runs each search alone.

    "Unsolvable" is a proof: no collision-free flight exists under the assumptions in
    docs/scenarios.md (for a moving field, none inside the searched box). "Solvable" may be optimistic: by
    about ``sqrt 2`` cells of passage width, and the acceleration limit is ignored. Deterministic;
    runs on the host, one field at a time.
    """
    r_uav = float(check_range("solvable.r_uav", r_uav, 0.0))
    r_goal = float(check_range("solvable.r_goal", r_goal, 0.0))
    margin = float(check_range("solvable.margin", margin, 0.0))
    v_max, t_max, resolution, reach_resolution, cell_steps = (
        float(check_range(f"solvable.{name}", value, 0.0, lo_open=True))
        for name, value in (("v_max", v_max), ("t_max", t_max), ("resolution", resolution),
                            ("reach_resolution", reach_resolution), ("cell_steps", cell_steps)))
    start, goal = np.asarray(scenarios.start, np.float64), np.asarray(scenarios.goal, np.float64)
    o = scenarios.obstacles
    batch = start.shape[:-1]
    n = int(np.prod(batch, dtype=int))
    m = np.asarray(o.radius).shape[-1]
    arrays = (start.reshape(n, 3), goal.reshape(n, 3), np.asarray(o.position).reshape(n, m, 3),
              np.asarray(o.velocity).reshape(n, m, 3), np.asarray(o.radius).reshape(n, m),
              np.asarray(o.cylinder).reshape(n, m), np.asarray(o.valid).reshape(n, m))
    out = [solvable_field(*(a[i] for a in arrays), r_uav=r_uav, v_max=v_max, t_max=t_max, r_goal=r_goal,
                          resolution=resolution, reach_resolution=reach_resolution, margin=margin, certify=certify,
                          cell_steps=cell_steps) for i in range(n)]
    return np.array(out, bool).reshape(batch)

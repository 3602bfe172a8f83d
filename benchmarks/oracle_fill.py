"""The static fields' solvability test as a batched JAX flood fill, against the oracle's certificates.

    python benchmarks/oracle_fill.py [--fields 512] [--families clutter paper_static trap] [--batch 64]
                                     [--json FILE]

An option for the oracle that was measured and not kept (docs/performance.md, "The oracle"): the static test
of ``jaxapf.scenarios.solvable`` (an 8-connected component search on a rasterised plane, cell 0.025 m) done
where the engine runs. Per field, the host works out what the oracle's search does before it labels (which
discs count, the grid of the start–goal frame, the start's cell: a few dozen numbers, timed apart as
``host_ms_per_field``); a jitted program vmapped over ``--batch`` fields then paints the discs on a grid
padded to the batch's largest, cuts the region a UAV could visit, and fills from the start until the goal is
reached or nothing changes: each round propagates along every free run of every row and column at once
(two running maxima, ``lax.cummax``) and then one diagonal step, so a round crosses a whole corridor, not one cell.
float64, so the cells are the search's own. The answers are checked against the search's
(``certify=False``); the time per field against today's oracle (certificates first) and the search alone,
interleaved per batch in one process.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from oracle import fields_of, vehicle_of  # noqa: E402


def _geometry(f, r_uav: float, v_max: float, t_max: float, r_goal: float, h: float, margin: float):
    """What the search of one static field works with before it labels (``solvability._connected``), or
    ``None`` where the oracle answers before any search (a start or goal inside an obstacle, a goal too far)."""
    from jaxapf.scenarios import solvability as s

    statics = ~f.moving()
    if np.any(f.clearance(f.start, 0.0, np.ones(statics.shape, bool)) < r_uav) or np.any(
            f.clearance(f.goal, 0.0, statics) < r_uav) or np.abs(f.goal - f.start).max() - r_goal > v_max * t_max:
        return None
    assert np.all(statics), "a static family"
    keep, r2 = s._static_discs(f, r_uav, h, margin)
    frame = s._static_frame(f, keep, r2, r_goal, h, v_max * t_max)
    grid = frame.grid
    return dict(origin=grid.origin, shape=(grid.ny, grid.nx), start=grid.cell(np.zeros(2)), centres=frame.centres,
                r2=frame.r2, goal=frame.goal, u=frame.u, s=f.start[:2], g=f.goal[:2], budget=frame.budget,
                goal_r=r_goal + h / math.sqrt(2))


def _pack(geoms: list[dict], slots: int, h: float) -> dict:
    """The fields' geometries as arrays with a leading batch axis (discs padded with ``r2 = 0``)."""
    n = len(geoms)
    out = {k: np.zeros((n, *shape)) for k, shape in (("origin", (2,)), ("centres", (slots, 2)), ("r2", (slots,)),
                                                      ("goal", (2,)), ("u", (2,)), ("s", (2,)), ("g", (2,)),
                                                      ("budget", ()), ("goal_r", ()))}
    out["shape"], out["start"] = np.zeros((n, 2), np.int64), np.zeros((n, 2), np.int64)
    for i, g in enumerate(geoms):
        for k in out:
            value = np.asarray(g[k])
            out[k][i, ...] = np.pad(value, [(0, slots - value.shape[0])] + [(0, 0)] * (value.ndim - 1)
                                    ) if k in ("centres", "r2") else value
    return out


def _carry(a, b):
    """Two stretches of a row in a row: free throughout, and reached at the end."""
    return a[0] & b[0], (a[1] & b[0]) | b[1]


def _fill_rows(reach, free, axis: int, reverse: bool, sweep: str):
    """Reach carried along every free run of ``axis``: ``out_i = reach_i | (out_{i-1} & free_i)``, cell by cell
    (``sweep="scan"``, ``lax.scan``) or in log depth (``"associative"``, ``lax.associative_scan``)."""
    if sweep == "associative":
        return jax.lax.associative_scan(_carry, (free, reach), axis=axis, reverse=reverse)[1]

    def step(carry, rf):
        out = rf[0] | (carry & rf[1])
        return out, out
    r, f = jnp.moveaxis(reach, axis, 0), jnp.moveaxis(free, axis, 0)
    _, out = jax.lax.scan(step, jnp.zeros_like(r[0]), (r, f), reverse=reverse)
    return jnp.moveaxis(out, 0, axis)


def _dilate(reach):
    """Every cell 8-adjacent to a reached one (or reached)."""
    p = jnp.pad(reach, 1)
    ny, nx = reach.shape
    return jnp.any(jnp.stack([p[1 + di:1 + di + ny, 1 + dj:1 + dj + nx]
                              for di in (-1, 0, 1) for dj in (-1, 0, 1)]), 0)


def solvable_fill(g: dict, grid: tuple[int, int], h: float, sweep: str) -> jnp.ndarray:
    """Whether the start's and a goal cell share an 8-connected free component, on a grid of ``grid`` cells
    (the field's own ``g["shape"]`` in its lower-left corner, the rest blocked)."""
    ny, nx = grid
    x = g["origin"][0] + (jnp.arange(nx) + 0.5) * h
    y = g["origin"][1] + (jnp.arange(ny) + 0.5) * h
    cx, cy = g["centres"][:, 0, None, None], g["centres"][:, 1, None, None]
    d2 = (y[None, :, None] - cy) ** 2 + (x[None, None, :] - cx) ** 2
    blocked = jnp.any(d2 < g["r2"][:, None, None], 0)
    wx = g["s"][0] + x[None, :] * g["u"][0] - y[:, None] * g["u"][1]
    wy = g["s"][1] + x[None, :] * g["u"][1] + y[:, None] * g["u"][0]
    cheb = (jnp.maximum(jnp.abs(wx - g["s"][0]), jnp.abs(wy - g["s"][1]))
            + jnp.maximum(jnp.abs(wx - g["g"][0]), jnp.abs(wy - g["g"][1])))
    blocked |= cheb > g["budget"]
    inside = (jnp.arange(ny)[:, None] < g["shape"][0]) & (jnp.arange(nx)[None, :] < g["shape"][1])
    free = inside & ~blocked
    goal = inside & ((y[:, None] - g["goal"][1]) ** 2 + (x[None, :] - g["goal"][0]) ** 2 <= g["goal_r"] ** 2)
    reach = free & (jnp.arange(ny)[:, None] == g["start"][0]) & (jnp.arange(nx)[None, :] == g["start"][1])

    def round_(state):
        reach, _ = state
        new = reach
        for axis in (1, 0):
            new = _fill_rows(_fill_rows(new, free, axis, False, sweep), free, axis, True, sweep)
        new = _dilate(new) & free
        return new, jnp.any(new != reach)

    def going(state):
        reach, changed = state
        return changed & ~jnp.any(reach & goal)

    reach, _ = jax.lax.while_loop(going, round_, (reach, jnp.any(reach)))
    return jnp.any(reach & goal)


SWEEPS = ("scan", "associative")
_RUN = jax.jit(jax.vmap(solvable_fill, in_axes=(0, None, None, None)), static_argnums=(1, 2, 3))


def prepare(fields, vehicle: dict, h: float) -> tuple[np.ndarray, dict | None, tuple[int, int] | None]:
    """The host's part, per field of a batch (numpy leaves): which fields reach the search (the others the
    oracle answers "unsolvable" before it), their geometries packed, and the padded grid (powers of two, so
    that a family compiles few programs)."""
    from jaxapf.scenarios import solvability as s

    o = fields.obstacles
    geoms = [_geometry(s._field(fields.start[i], fields.goal[i], o.position[i], o.velocity[i], o.radius[i],
                                o.cylinder[i], o.valid[i]), h=h, margin=s.MARGIN, **vehicle)
             for i in range(len(fields.start))]
    asked = np.array([g is not None for g in geoms])
    if not asked.any():
        return asked, None, None
    packed = _pack([g for g in geoms if g is not None], np.asarray(o.radius).shape[-1], h)
    return asked, packed, tuple(int(2 ** math.ceil(math.log2(v))) for v in packed["shape"].max(0))


def fill(asked: np.ndarray, packed: dict | None, grid: tuple[int, int] | None, h: float, sweep: str) -> np.ndarray:
    """The JAX fill's answer per field (float64)."""
    answer = np.zeros(asked.shape, bool)
    if packed is not None:
        with jax.enable_x64(True):
            answer[asked] = np.asarray(jax.block_until_ready(_RUN(packed, grid, h, sweep)))
    return answer


def family(name: str, count: int, batch: int, h: float) -> dict:
    """The JAX fill (both sweeps) against the oracle with and without certificates on ``count`` fields of
    ``name``, interleaved per batch."""
    from jaxapf.scenarios import solvable

    fields, swarm = fields_of(name, count)
    assert not swarm
    vehicle = vehicle_of(name)
    seconds = dict.fromkeys(("certified", "search", "host", *SWEEPS), 0.0)
    compile_s = dict.fromkeys(SWEEPS, 0.0)
    answers = {k: [] for k in ("search", *SWEEPS)}
    grids, cells = set(), []
    for first in range(0, count, batch):
        block = jax.tree_util.tree_map(lambda x, first=first: np.asarray(x[first:first + batch]), fields)
        t = time.perf_counter()
        certified = solvable(block, **vehicle)
        seconds["certified"] += time.perf_counter() - t
        t = time.perf_counter()
        search = solvable(block, **vehicle, certify=False)
        seconds["search"] += time.perf_counter() - t
        assert np.array_equal(search, certified)
        answers["search"].append(search)
        t = time.perf_counter()
        asked, packed, grid = prepare(block, vehicle, h)
        seconds["host"] += time.perf_counter() - t
        cells += [int(np.prod(v)) for v in packed["shape"]] if packed is not None else []
        for sweep in SWEEPS:
            if packed is not None and (grid, sweep) not in grids:
                t = time.perf_counter()
                with jax.enable_x64(True):
                    _RUN.lower(packed, grid, h, sweep).compile()
                compile_s[sweep] += time.perf_counter() - t
                grids.add((grid, sweep))
            t = time.perf_counter()
            answers[sweep].append(fill(asked, packed, grid, h, sweep))
            seconds[sweep] += time.perf_counter() - t
    reference = np.concatenate(answers["search"])
    per = lambda k: round(1e3 * seconds[k] / count, 3)  # noqa: E731
    best = min(SWEEPS, key=lambda k: seconds[k])
    return {"fields": count, "batch": batch, "vehicle": vehicle, "solvable": round(float(reference.mean()), 4),
            "cells_median": int(np.median(cells)), "cells_max": int(max(cells)),
            "grids": sorted([list(g), k] for g, k in grids),
            "differ": {k: int((np.concatenate(answers[k]) != reference).sum()) for k in SWEEPS},
            "certified_ms_per_field": per("certified"), "search_ms_per_field": per("search"),
            "host_ms_per_field": per("host"), "fill_ms_per_field": {k: per(k) for k in SWEEPS},
            "compile_s": {k: round(v, 2) for k, v in compile_s.items()}, "best": best,
            "best_over_certified": round((seconds[best] + seconds["host"]) / seconds["certified"], 1)}


def main(argv: list[str] | None = None) -> int:
    from jaxapf.bench.engine import environment
    from jaxapf.scenarios.solvability import RESOLUTION

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fields", type=int, default=512)
    p.add_argument("--families", nargs="*", default=["clutter", "paper_static", "trap"])
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--json", type=pathlib.Path)
    args = p.parse_args(argv)
    result = {"command": "python benchmarks/oracle_fill.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "date": datetime.date.today().isoformat(), "environment": environment("float64"), "families": {}}
    for name in args.families:
        r = result["families"][name] = family(name, args.fields, args.batch, RESOLUTION)
        print(f"{name}: answers differing {r['differ']}; ms per field: certificates {r['certified_ms_per_field']}, "
              f"search {r['search_ms_per_field']}, JAX fill {r['fill_ms_per_field']} + host {r['host_ms_per_field']} "
              f"(the best {r['best_over_certified']}x the certificates); compile {r['compile_s']} s", flush=True)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 1 if any(any(r["differ"].values()) for r in result["families"].values()) else 0


if __name__ == "__main__":
    sys.exit(main())

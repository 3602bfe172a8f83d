"""The nearest feasible point (jaxapf.projection): against OSQP (box; ball through its multiplier)
on random feasible problems; on random infeasible ones the least largest violation, against
scipy's linprog (box) and SLSQP (ball); infeasibility reported, gradients against finite
differences; with only the rows that bind soonest kept, the full problem's answer whenever it is
certified exact, and a hand-made case it cannot be."""

from __future__ import annotations

import functools
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxapf.control.cbf import INFEASIBLE_TOL
from jaxapf.projection import nearest_feasible

LIMIT = 3.0
ROWS = 16  # problems padded to 16 rows (zero rows are ignored): one compiled solver for all
PROJECT = jax.jit(nearest_feasible, static_argnums=(3, 4, 5))


def _padded(g: np.ndarray, b: np.ndarray) -> tuple[jax.Array, jax.Array]:
    m = g.shape[0]
    return (jnp.asarray(np.vstack([g, np.zeros((ROWS - m, 3))]), jnp.float32),
            jnp.asarray(np.concatenate([b, -np.ones(ROWS - m)]), jnp.float32))


def _osqp(x0, g, b, limit=None, weight=1.0):
    """``argmin ½ weight |x|² - x0·x`` s.t. ``g x >= b`` (and the box ``|x_i| <= limit``) by OSQP."""
    osqp = pytest.importorskip("osqp")
    from scipy import sparse

    n = x0.size
    box = limit is not None
    A = sparse.csc_matrix(np.vstack([g, np.eye(n)]) if box else g)
    lo = np.concatenate([b, -limit * np.ones(n)]) if box else b
    hi = np.concatenate([np.full(b.size, np.inf), limit * np.ones(n)]) if box else np.full(b.size, np.inf)
    solver = osqp.OSQP()
    solver.setup(P=sparse.csc_matrix(weight * np.eye(n)), q=-x0, A=A, l=lo, u=hi, eps_abs=1e-10, eps_rel=1e-10,
                 max_iter=400000, polishing=True, verbose=False)
    # OSQP >= 1.0 warns (PendingDeprecationWarning, once per solve) unless told whether to raise; 0.6 has no switch
    res = solver.solve(**({"raise_error": False} if int(str(osqp.__version__).split(".")[0]) >= 1 else {}))
    assert res.info.status == "solved"
    return res.x


def _ball_by_duality(x0, g, b, limit):
    """The ball problem through its multiplier λ of ``|x|² <= L²``: for fixed λ the minimiser is
    OSQP's projection with weight 1 + λ, and ``|x(λ)|`` falls with λ (the dual's derivative), so
    bisection finds the λ where the ball is just met."""
    x = _osqp(x0, g, b)
    if x @ x <= limit**2:
        return x
    lo, hi = 0.0, 1.0
    while np.linalg.norm(_osqp(x0, g, b, weight=1.0 + hi)) > limit:
        lo, hi = hi, 2.0 * hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.linalg.norm(_osqp(x0, g, b, weight=1.0 + mid)) > limit else (lo, mid)
    return _osqp(x0, g, b, weight=1.0 + hi)


def _problem(seed: int, region: str):
    """Random unit rows with a known feasible point inside the region."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, ROWS + 1))
    g = rng.normal(size=(m, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    inside = rng.uniform(-LIMIT, LIMIT, 3) * 0.8
    if region == "ball":
        inside *= 0.8 * LIMIT / max(np.linalg.norm(inside), LIMIT)
    b = g @ inside - rng.uniform(0, 0.5, m)
    x0 = rng.uniform(-2 * LIMIT, 2 * LIMIT, 3)
    return x0, g, b, inside


@pytest.mark.parametrize("seed", range(40))
def test_box_matches_osqp_on_feasible_problems(seed):
    """The box problem (the CBF filter's): OSQP's solution, every constraint within the tolerance
    that counts a step infeasible."""
    x0, g, b, _ = _problem(seed, "box")
    x, worst, _ = PROJECT(jnp.asarray(x0, jnp.float32), *_padded(g, b), LIMIT, "box")
    np.testing.assert_allclose(np.asarray(x), _osqp(x0, g, b, LIMIT), atol=1e-4)
    assert float(worst) <= INFEASIBLE_TOL
    assert np.all(np.abs(np.asarray(x)) <= LIMIT + 1e-6)


@pytest.mark.parametrize("seed", range(40))
def test_ball_matches_the_dual_solution_on_feasible_problems(seed):
    """The ball problem (the velocity-obstacle planner's): the solution by duality and OSQP, within
    the ball."""
    x0, g, b, _ = _problem(seed, "ball")
    x, worst, _ = PROJECT(jnp.asarray(x0, jnp.float32), *_padded(g, b), LIMIT, "ball")
    np.testing.assert_allclose(np.asarray(x), _ball_by_duality(x0, g, b, LIMIT), atol=2e-4)
    assert float(worst) <= INFEASIBLE_TOL
    assert np.linalg.norm(np.asarray(x)) <= LIMIT * (1 + 1e-6)


@pytest.mark.parametrize("region", ["box", "ball"])
def test_a_feasible_point_passes_unchanged(region):
    g = jnp.asarray([[1.0, 0.0, 0.0]])
    x, worst, _ = PROJECT(jnp.asarray([1.0, 1.5, -1.0]), *_padded(np.asarray(g), np.asarray([0.5])), LIMIT, region)
    np.testing.assert_array_equal(np.asarray(x), [1.0, 1.5, -1.0])
    assert float(worst) == 0.0


@pytest.mark.parametrize("region", ["box", "ball"])
def test_incompatible_constraints_are_reported(region):
    """``x_1 >= 1`` and ``-x_1 >= 1`` cannot both hold; nor can ``x_1 >= 5`` within the region."""
    for g, b in [([[1.0, 0, 0], [-1.0, 0, 0]], [1.0, 1.0]), ([[1.0, 0, 0]], [5.0])]:
        _, worst, _ = PROJECT(jnp.zeros(3), *_padded(np.asarray(g), np.asarray(b)), LIMIT, region)
        assert float(worst) > INFEASIBLE_TOL


def _infeasible(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random unit rows asking for more than the region allows (``b`` in [0.3 L, 1.5 L])."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(2, ROWS + 1))
    g = rng.normal(size=(m, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    return rng.uniform(-2 * LIMIT, 2 * LIMIT, 3), g, rng.uniform(0.3 * LIMIT, 1.5 * LIMIT, m)


def _least_violation_box(g, b, limit=LIMIT):
    """``min t`` s.t. ``b_j - g_j·x <= t``, ``|x_i| <= L`` by scipy's linprog (HiGHS), float64."""
    from scipy.optimize import linprog

    m = g.shape[0]
    res = linprog(np.r_[0.0, 0.0, 0.0, 1.0], A_ub=np.hstack([-g, -np.ones((m, 1))]), b_ub=-b,
                  bounds=[(-limit, limit)] * 3 + [(None, None)], method="highs")
    assert res.status == 0
    return res.fun


def _least_violation_ball(g, b, seed):
    """The same within the ball by SLSQP (convex: the best of a few starts), float64."""
    from scipy.optimize import minimize

    rng = np.random.default_rng(seed)
    best = np.inf
    for _ in range(4):
        z0 = np.r_[rng.uniform(-1, 1, 3), 2 * LIMIT]
        res = minimize(lambda z: z[3], z0, method="SLSQP", options={"ftol": 1e-12, "maxiter": 500},
                       constraints=[{"type": "ineq", "fun": lambda z: g @ z[:3] + z[3] - b},
                                    {"type": "ineq", "fun": lambda z: LIMIT**2 - z[:3] @ z[:3]}])
        if res.success and np.all(g @ res.x[:3] + res.x[3] - b >= -1e-8):
            best = min(best, res.fun)
    return best


@pytest.mark.parametrize("region", ["box", "ball"])
def test_infeasible_problems_get_the_least_largest_violation(region):
    """On 60 random infeasible problems the largest violation at the returned point is the least the
    region allows (linprog's minimax LP for the box, SLSQP for the ball) within 5e-5 (1 + L); the
    point lies in the region. (The former rule, the candidate of least violation, was a median 1.27x
    the optimum on these.)"""
    problems = [p for p in map(_infeasible, range(1000, 1100)) if _least_violation_box(p[1], p[2]) > 0.05][:60]
    assert len(problems) == 60  # (the ball lies in the box: infeasible in the box, infeasible in the ball)
    solve = jax.jit(jax.vmap(nearest_feasible, in_axes=(0, 0, 0, None, None)), static_argnums=(3, 4))
    padded = [_padded(g, b) for _, g, b in problems]
    x, worst, _ = solve(jnp.asarray(np.array([x0 for x0, _, _ in problems]), jnp.float32),
                     jnp.stack([g for g, _ in padded]), jnp.stack([b for _, b in padded]), LIMIT, region)
    x, worst = np.asarray(x, np.float64), np.asarray(worst, np.float64)
    for i, (_, g, b) in enumerate(problems):
        best = _least_violation_box(g, b) if region == "box" else _least_violation_ball(g, b, i)
        assert worst[i] == pytest.approx(np.max(b - g @ x[i]), abs=1e-5)
        assert abs(worst[i] - best) <= 5e-5 * (1 + LIMIT), (i, worst[i], best)
        if region == "box":
            assert np.all(np.abs(x[i]) <= LIMIT)
        else:
            assert np.linalg.norm(x[i]) <= LIMIT * (1 + 1e-6)


@pytest.mark.parametrize("region", ["box", "ball"])
def test_among_the_least_violating_points_the_nearest_is_returned(region):
    """Hand-made: ``x_1 >= 1`` and ``-x_1 >= 1`` are violated by 1 at best, on the whole plane
    ``x_1 = 0``; from ``x0 = (2, 1, -1)`` the point returned is its projection ``(0, 1, -1)``."""
    g, b = np.asarray([[1.0, 0, 0], [-1.0, 0, 0]]), np.asarray([1.0, 1.0])
    x, worst, _ = PROJECT(jnp.asarray([2.0, 1.0, -1.0]), *_padded(g, b), LIMIT, region)
    np.testing.assert_allclose(np.asarray(x), [0.0, 1.0, -1.0], atol=1e-4)
    assert float(worst) == pytest.approx(1.0, abs=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("region, x0", [("box", [-1.0, 0.3, 0.7]), ("ball", [-1.0, 0.3, 0.7]),
                                        ("ball", [2.0, -4.0, 1.0]), ("ball", [-3.0, 4.0, 2.0])])
def test_gradient_matches_finite_differences(region, x0):
    """d x*/d x0 through the selected candidate (planes only, the sphere with one and with two
    planes active), in float64, against central differences."""
    with jax.enable_x64(True):
        g = jnp.asarray([[0.6, 0.8, 0.0], [0.0, -1.0, 0.0]], jnp.float64)
        b = jnp.asarray([0.5, -2.0], jnp.float64)
        f = jax.jit(lambda x: jnp.sum(nearest_feasible(x, g, b, LIMIT, region)[0] * jnp.asarray([1.0, 2.0, 3.0])))
        x0 = jnp.asarray(x0, jnp.float64)
        grad = np.asarray(jax.jit(jax.grad(f))(x0))
        eps = 1e-6
        fd = [(f(x0.at[i].add(eps)) - f(x0.at[i].add(-eps))) / (2 * eps) for i in range(3)]
        np.testing.assert_allclose(grad, np.asarray(fd), rtol=1e-4, atol=1e-6)
        assert np.all(np.isfinite(grad))
        # four rows that hold everywhere in the region added, the two that bind soonest kept: the same gradient
        far = jnp.concatenate([g, jnp.asarray([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, 0, 0]])])
        kept = jax.jit(lambda x: jnp.sum(nearest_feasible(x, far, jnp.concatenate([b, jnp.full(4, -10.0)]), LIMIT,
                                                          region, 2)[0] * jnp.asarray([1.0, 2.0, 3.0])))
        np.testing.assert_allclose(np.asarray(jax.jit(jax.grad(kept))(x0)), grad, rtol=1e-12, atol=1e-12)


def _crowded(seed: int, region: str, rows: int = 40, decoys: int = 0):
    """Many unit rows (``rows``), most of them holding everywhere in the region (far obstacles): a few
    binding ones through a known feasible point, the rest with ``b`` below ``-L‖g‖`` by up to 3. With
    ``decoys``, that many of the rest can bind in a corner of the region away from the feasible point
    (``b + L‖g‖`` up to ``2 L‖g‖``, above the binding rows' often; held with slack 0.1 there): the rows
    kept first miss rows the answer needs."""
    rng = np.random.default_rng(seed)
    g = rng.normal(size=(rows, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    inside = rng.uniform(-0.5, 0.5, 3) * LIMIT
    reach = np.abs(g).sum(axis=1) if region == "box" else np.ones(rows)
    b = -LIMIT * reach - rng.uniform(0.0, 3.0, rows)
    binding = rng.choice(rows, int(rng.integers(1, 7)), replace=False)
    b[binding] = g[binding] @ inside - rng.uniform(0.0, 0.5, binding.size)
    rest = np.setdiff1d(np.arange(rows), binding)[:decoys]
    b[rest] = np.minimum(g[rest] @ inside - 0.1, LIMIT * reach[rest] * (rng.uniform(1.0, 2.0, rest.size) - 1.0))
    return rng.uniform(-2 * LIMIT, 2 * LIMIT, 3), g, b


@pytest.mark.slow
@pytest.mark.parametrize("region", ["box", "ball"])
def test_keeping_the_rows_that_bind_soonest_gives_the_full_answer(region):
    """40 rows, at most 6 of which can bind in the region: with 8 rows kept every answer is certified
    exact and is the full solve's, up to rounding (the kept rows' candidates are formed in another
    order); with every row kept (``rows`` >= 40 or 0) the program is the full one, bit for bit."""
    problems = [_crowded(seed, region) for seed in range(30)]
    x0 = jnp.asarray(np.array([p[0] for p in problems]), jnp.float32)
    g = jnp.asarray(np.array([p[1] for p in problems]), jnp.float32)
    b = jnp.asarray(np.array([p[2] for p in problems]), jnp.float32)
    solve = jax.jit(jax.vmap(nearest_feasible, in_axes=(0, 0, 0, None, None, None)), static_argnums=(3, 4, 5))
    full, full_worst, full_exact = solve(x0, g, b, LIMIT, region, 0)
    kept, kept_worst, kept_exact = solve(x0, g, b, LIMIT, region, 8)
    assert np.all(np.asarray(full_exact)) and np.all(np.asarray(kept_exact))
    np.testing.assert_allclose(np.asarray(kept), np.asarray(full), atol=2e-5)
    np.testing.assert_allclose(np.asarray(kept_worst), np.asarray(full_worst), atol=2e-5)
    every = solve(x0, g, b, LIMIT, region, 40)
    np.testing.assert_array_equal(np.asarray(every[0]), np.asarray(full))


@pytest.mark.slow
@pytest.mark.parametrize("region", ["box", "ball"])
def test_the_rounds_take_in_the_rows_the_answer_needs(region):
    """40 rows, 16 of them decoys that can bind in a far corner of the region, 8 kept (float64): the
    first relaxation (the 8 rows that bind soonest, solved alone) misses the full answer on most
    problems, by up to the region's size; with the rounds every answer is certified exact and is the
    full solve's, up to rounding."""
    problems = [_crowded(seed, region, decoys=16) for seed in range(30)]
    with jax.enable_x64(True):
        x0, g, b = (jnp.asarray(np.array([p[i] for p in problems]), jnp.float64) for i in range(3))
        solve = jax.jit(jax.vmap(nearest_feasible, in_axes=(0, 0, 0, None, None, None)), static_argnums=(3, 4, 5))
        full, full_worst, _ = solve(x0, g, b, LIMIT, region, 0)
        kept, kept_worst, exact = solve(x0, g, b, LIMIT, region, 8)
        reach = jnp.sum(jnp.abs(g), axis=2) if region == "box" else jnp.ones(b.shape)
        soonest = jax.lax.top_k(b + LIMIT * reach, 8)[1]
        first = solve(x0, jnp.take_along_axis(g, soonest[..., None], 1), jnp.take_along_axis(b, soonest, 1),
                      LIMIT, region, 0)[0]
    missed = np.abs(np.asarray(first) - np.asarray(full)).max(axis=1) > 0.1
    assert missed.sum() >= 15
    assert np.all(np.asarray(exact))
    np.testing.assert_allclose(np.asarray(kept), np.asarray(full), atol=1e-9)
    np.testing.assert_allclose(np.asarray(kept_worst), np.asarray(full_worst), atol=1e-9)


@pytest.mark.parametrize("region", ["box", "ball"])
def test_a_row_left_out_that_the_answer_violates_is_taken_in(region):
    """Hand-made: four rows that can all bind, ``x_1 >= 1.0, 1.1, 1.2`` and ``x_2 >= 1.05``. With two kept,
    the first solve (``x_1 >= 1.2`` and ``x_1 >= 1.1``, largest ``b + L‖g‖``) answers ``(1.2, 0, 0)``, which
    ``x_2 >= 1.05`` violates; the second keeps the active ``x_1 >= 1.2`` and takes ``x_2 >= 1.05`` in:
    ``(1.2, 1.05, 0)``, the full answer, certified, with the full answer's derivative (``∂x_1/∂b_3 =
    ∂x_2/∂b_4 = 1``). With one kept, the active row holds the only place every round; the wider solve
    (two rows) finds the full answer, certified and returned, but its derivative is the kept row's solve's
    (``∂x_2/∂b_4 = 0``), as documented."""
    g = jnp.asarray([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    b = jnp.asarray([1.0, 1.1, 1.2, 1.05])
    full = np.zeros((3, 4))
    full[0, 2] = full[1, 3] = 1.0
    for rows in (0, 2, 3, 1):
        x, worst, exact = PROJECT(jnp.zeros(3), g, b, LIMIT, region, rows)
        np.testing.assert_allclose(np.asarray(x), [1.2, 1.05, 0.0], atol=1e-6)
        assert bool(exact) and float(worst) == 0.0
    for rows, expected in ((2, full), (1, full * [[1], [0], [0]])):
        answer = functools.partial(nearest_feasible, jnp.zeros(3), g, limit=LIMIT, region=region, rows=rows)
        jacobian = jax.jit(jax.jacfwd(lambda b, answer=answer: answer(b=b)[0]))(b)
        np.testing.assert_allclose(np.asarray(jacobian), expected, atol=1e-6)


@pytest.mark.parametrize("region", ["box", "ball"])
def test_on_an_infeasible_problem_a_row_left_out_that_the_answer_violates_more_is_reported(region):
    """Hand-made: ``x_1 >= 1`` and ``-x_1 >= 1`` are violated by 1 at best (on ``x_1 = 0``), ``x_2 >= 0.5``
    can hold there. From ``(0, -2, 0)`` the full answer keeps the least violation 1 for every row:
    ``(0, -0.5, 0)``, all three rows active. No two rows hold that answer: ``x_1 >= 1`` and ``-x_1 >= 1``
    stay at ``(0, -2, 0)`` (the third violated by 2.5), either of them with ``x_2 >= 0.5`` moves to
    ``x_1 = ±1`` (the other violated by 2). With one row kept (and so two in the wider solve) the answer
    is not certified exact, whatever is kept; with two, the wider solve holds all three and certifies it."""
    g = jnp.asarray([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0]])
    b = jnp.asarray([1.0, 1.0, 0.5])
    x0 = jnp.asarray([0.0, -2.0, 0.0])
    for rows in (0, 2):
        x, worst, exact = PROJECT(x0, g, b, LIMIT, region, rows)
        np.testing.assert_allclose(np.asarray(x), [0.0, -0.5, 0.0], atol=1e-4)
        assert bool(exact) and float(worst) == pytest.approx(1.0, abs=1e-4)
    x, worst, exact = PROJECT(x0, g, b, LIMIT, region, 1)
    assert not bool(exact) and float(worst) >= 2.0 - 1e-4


#: A CBF step of a 16-UAV ``formation_gap`` swarm (study 16, selection 3) that the rounds alone could not
#: certify with 8 rows: 32 vertical obstacles' rows (no z), infeasible (least violation 0.0372), two rows
#: nearly opposite (a thin wedge). In float32 a relaxation holding both missed its minimiser and the
#: rounds cycled between two sets of rows.
WEDGE_X0 = [0.5943934321403503, -2.8588309288024902, 0.0]
WEDGE_G = [
    -0.20887312293052673, 0.9779428243637085, -0.32352888584136963, 0.9462183117866516,
    -0.4256097674369812, 0.9049068689346313, -0.5137619972229004, 0.8579327464103699,
    -0.5882512331008911, 0.8086782097816467, -0.6503316164016724, 0.7596504092216492,
    -0.701688289642334, 0.7124840021133423, -0.7440637350082397, 0.6681085824966431,
    -0.779057502746582, 0.6269524097442627, -0.8080463409423828, 0.5891189575195312,
    -0.8321715593338013, 0.5545181632041931, -0.8523597717285156, 0.5229558348655701,
    0.42661985754966736, 0.9044310450553894, 0.5141814947128296, 0.857681393623352,
    0.5881439447402954, 0.8087562322616577, 0.6497885584831238, 0.7601150870323181,
    0.7008041143417358, 0.7133537530899048, 0.7429242134094238, 0.6693755984306335,
    0.7777343392372131, 0.6285930275917053, 0.8065969347953796, 0.591101884841919,
    0.8306401371955872, 0.5568096041679382, 0.8507797718048096, 0.5255224704742432,
    0.8677504062652588, 0.49700018763542175, 0.882138729095459, 0.47098952531814575,
    0.9997595548629761, 0.02192876860499382, -0.2508891522884369, -0.9680157899856567,
    -0.9966636896133423, -0.08161868155002594, 0.7150400876998901, -0.6990833878517151,
    -0.8090771436691284, -0.5877023339271545, 0.9996498227119446, -0.026461275294423103,
    0.30259501934051514, -0.9531192779541016, -0.23893964290618896, -0.9710344076156616,
]
WEDGE_B = [
    0.13424964249134064, 0.015759406611323357, -0.14934271574020386, -0.34991493821144104,
    -0.5756733417510986, -0.818242609500885, -1.071362853050232, -1.3306330442428589,
    -1.5930945873260498, -1.8568297624588013, -2.120638847351074, -2.383798360824585,
    -0.22834065556526184, -0.4445370137691498, -0.6832079887390137, -0.9363083839416504,
    -1.1979670524597168, -1.4641551971435547, -1.7322384119033813, -2.000565528869629,
    -2.2681491374969482, -2.5344347953796387, -2.799142837524414, -3.062164783477783,
    -0.20933406054973602, -0.09446489065885544, -0.46612170338630676, -0.39863303303718567,
    -0.7975722551345825, -0.7286571264266968, -0.04983571916818619, -0.20778827369213104,
]


def test_rounds_that_cycle_on_a_thin_wedge_end_in_the_full_answer():
    """The step above with 8 rows kept: after the rounds, one solve with twice the rows finds the rows the
    answer needs: certified, and the full solve's answer up to rounding (float32, as in the study)."""
    g = np.zeros((32, 3), np.float32)
    g[:, :2] = np.asarray(WEDGE_G, np.float32).reshape(32, 2)
    args = jnp.asarray(WEDGE_X0, jnp.float32), jnp.asarray(g), jnp.asarray(WEDGE_B, jnp.float32)
    full, full_worst, _ = PROJECT(*args, 3.0, "box", 0)
    kept, kept_worst, exact = PROJECT(*args, 3.0, "box", 8)
    assert bool(exact) and float(full_worst) == pytest.approx(0.03715, abs=1e-4)
    np.testing.assert_allclose(np.asarray(kept), np.asarray(full), atol=1e-6)
    assert float(kept_worst) == pytest.approx(float(full_worst), abs=1e-6)


def test_every_step_a_swarm_reported_infeasible_is_infeasible():
    """The case read as float32 phantoms (``swarm_clutter``, 4 UAVs, seed 3, field 2, ``basic`` + CBF, N = 10,
    15 iterations, every row): 11 ``cbf_infeasible_steps`` on AVX2 and SSE4.2 CPUs, 0 on AVX-512 and with 8
    rows kept. Agent 0's 20 projections at steps 60-79 of that flight (tests/data): the float32 solve with
    every row reports infeasible exactly the 11 that linprog (float64) finds infeasible, with its least
    violation, and the certified 8-row solve agrees. The flights differ because their trajectories do (a
    1e-6 rounding difference turns a decision at step 32), not because a feasible step was called infeasible."""
    case = np.load(pathlib.Path(__file__).parent / "data" / "swarm_clutter_cbf_steps.npz")
    limit = float(case["limit"])
    solve = jax.jit(jax.vmap(nearest_feasible, in_axes=(0, 0, 0, None, None, None)), static_argnums=(3, 4, 5))
    args = jnp.asarray(case["x0"]), jnp.asarray(case["g"]), jnp.asarray(case["b"])
    _, full, _ = solve(*args, limit, "box", 0)
    _, kept, exact = solve(*args, limit, "box", 8)
    # the flight's own answers, up to the solver's rounding slack (another compiled program rounds otherwise)
    np.testing.assert_allclose(np.asarray(full), case["violation"], atol=1e-6 * (1 + limit))
    best = []
    for g, b in zip(case["g"].astype(np.float64), case["b"].astype(np.float64)):
        usable = np.any(g != 0, axis=1)
        best.append(max(0.0, _least_violation_box(g[usable], b[usable], limit)))
    best = np.asarray(best)
    assert int(np.sum(best > INFEASIBLE_TOL)) == 11
    np.testing.assert_array_equal(np.asarray(full) > INFEASIBLE_TOL, best > INFEASIBLE_TOL)
    np.testing.assert_allclose(np.asarray(full), best, atol=5e-5 * (1 + limit))
    assert bool(np.all(np.asarray(exact)))
    np.testing.assert_allclose(np.asarray(kept), np.asarray(full), atol=1e-5)


def test_every_row_kept_is_exact_whatever_the_input():
    """Without rows left out the answer is the full problem's by construction: ``exact`` is True even for
    a NaN input (its NaN answer is not a truncation)."""
    g = jnp.asarray([[1.0, 0, 0]])
    for rows in (0, 1, 5):
        assert bool(PROJECT(jnp.asarray([jnp.nan, 0.0, 0.0]), g, jnp.asarray([0.5]), LIMIT, "box", rows)[2])


@pytest.mark.slow
def test_the_closed_loops_gradient_with_rows_kept_is_the_full_problems():
    """``basic`` with the CBF filter on a ``clutter`` field, float64, 4 s: the gradient of the final
    squared distance from the origin in ``cbf_p1`` with 4 rows kept (the loop's answer, differentiated as
    the kept rows' solve) is the one with every row, and central differences'."""
    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.engine.loop import rollout
    from jaxapf.scenarios import family_params, make_scenarios

    with jax.enable_x64(True):
        field = jax.tree_util.tree_map(lambda x: jnp.asarray(x[3], jnp.float64) if x.dtype == jnp.float32 else x[3],
                                       make_scenarios(0, family_params("clutter"), 8))
        grads = []
        for rows in (0, 4):
            sim = SimConfig.from_flat(method="basic", filter="cbf", t_max=4.0, projection_rows=rows)
            loss = jax.jit(lambda p1, sim=sim: jnp.sum(rollout(field, Gains(cbf_p1=p1), sim,
                                                               MPCConfig(horizon=8, iters=10)).position[-1] ** 2))
            p1, h = jnp.float64(1.0), 1e-6
            grads.append((float(jax.jit(jax.grad(loss))(p1)), float((loss(p1 + h) - loss(p1 - h)) / (2 * h))))
    assert abs(grads[0][0]) > 1.0  # the filter acts
    np.testing.assert_allclose(grads[1][0], grads[0][0], rtol=1e-9)
    np.testing.assert_allclose(grads[1][0], grads[1][1], rtol=1e-6)

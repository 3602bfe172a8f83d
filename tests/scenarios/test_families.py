"""Scenario families: shapes and padding, clear endpoints, determinism, family geometry, validation.

Every batch here has 8 fields, so each family compiles once and the compiled program is reused.
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.datatypes import Obstacles, clearance
from jaxapf.scenarios import (
    FAMILIES,
    TRAP_KINDS,
    clear_endpoints,
    family_params,
    field_key,
    make_scenario,
    make_scenarios,
)
from jaxapf.validation import ConfigError

N = 8
DEFAULTS = {f: family_params(f) for f in FAMILIES}


@jax.jit
def _endpoint_clearance(scenarios, r_uav):
    """(F, 2, M): clearance of start and goal to every obstacle at t = 0 (+inf for padded slots)."""

    def one(s):
        ends = jnp.stack([s.start, s.goal])
        return jax.vmap(lambda p: clearance(p, s.obstacles, 0.0, r_uav))(ends)

    return jax.vmap(one)(scenarios)


_clear = jax.jit(clear_endpoints)


def _batch(params, seed=0, first=0):
    return jax.device_get(make_scenarios(seed, params, np.arange(first, first + N)))


def _frame(s):
    """Unit start–goal direction (F, 3), its left normal (F, 3) and the distance (F,)."""
    d = s.goal - s.start
    length = np.linalg.norm(d, axis=-1)
    u = d / length[:, None]
    left = np.stack([-u[:, 1], u[:, 0], np.zeros_like(u[:, 0])], -1)
    return u, left, length


def _local(s):
    """Obstacle centres and velocities in the local frame: (along, lateral) components, (F, M)."""
    u, left, _ = _frame(s)
    rel = s.obstacles.position - s.start[:, None]
    vel = s.obstacles.velocity
    return (np.einsum("fmk,fk->fm", rel, u), np.einsum("fmk,fk->fm", rel, left),
            np.einsum("fmk,fk->fm", vel, u), np.einsum("fmk,fk->fm", vel, left))


# --------------------------------------------------------------------------------------------
# every family
# --------------------------------------------------------------------------------------------


def test_family_names_and_recommended_episode_lengths():
    assert FAMILIES.names() == ("paper_static", "paper_dynamic", "trap", "clutter", "crossing", "head_on",
                        "overtake", "dynamic")
    for family, p in DEFAULTS.items():
        assert p.family == family
        assert p.t_max == (300.0 if family == "paper_dynamic" else 60.0)
        assert hash(p) == hash(family_params(family))


@pytest.mark.parametrize("family", FAMILIES.names())
def test_shapes_dtypes_and_padding(family):
    p = DEFAULTS[family]
    s = _batch(p)
    m = p.max_obstacles
    o = s.obstacles
    assert s.start.shape == s.goal.shape == (N, 3) and s.start.dtype == np.float32
    assert o.position.shape == o.velocity.shape == (N, m, 3)
    assert o.radius.shape == o.cylinder.shape == o.valid.shape == (N, m)
    assert o.position.dtype == o.velocity.dtype == o.radius.dtype == np.float32
    assert o.cylinder.dtype == o.valid.dtype == np.bool_
    pad = ~o.valid
    assert np.all(o.position[pad] == 1e6) and np.all(o.velocity[pad] == 0) and np.all(o.radius[pad] == 0)
    assert not np.any(o.cylinder[pad])
    assert np.all(o.cylinder[o.valid]) and np.all(o.radius[o.valid] > 0)
    assert np.all(o.valid.sum(axis=1) >= 1)
    assert np.all(s.start[:, 2] == p.altitude) and np.allclose(s.goal[:, 2], p.altitude)
    assert np.allclose(o.position[o.valid][:, 2], p.altitude) and np.all(o.velocity[..., 2] == 0)
    length = np.linalg.norm(s.goal - s.start, axis=1)
    assert np.all((length >= p.distance[0] - 1e-4) & (length <= p.distance[1] + 1e-4))


@pytest.mark.parametrize("family", FAMILIES.names())
@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), first=st.integers(0, 100_000))
def test_start_and_goal_are_clear_at_t0(family, seed, first):
    p = DEFAULTS[family]
    c = np.asarray(_endpoint_clearance(make_scenarios(seed, p, np.arange(first, first + N)), p.r_uav))
    assert np.all(c >= 0.0)
    assert np.all(c[:, 0] >= p.start_margin - 1e-5)
    assert np.all(c[:, 1] >= p.goal_margin - 1e-5)


@pytest.mark.parametrize("family", ["paper_static", "paper_dynamic", "clutter", "dynamic"])
def test_no_family_with_lingering_obstacles_puts_one_within_d_s_of_the_goal(family):
    # GNRON (goal non-reachable with an obstacle nearby) is trap's gnron kind, not an accident of
    # another family: at t = 0 every goal is at least the default d_s = 4 m clear (the passing
    # movers of crossing, head_on and overtake keep 0.25 m: they are gone when the UAV arrives)
    p = DEFAULTS[family]
    assert p.goal_margin == 4.0
    c = np.asarray(_endpoint_clearance(make_scenarios(0, p, np.arange(64)), p.r_uav))
    assert np.all(c[:, 1] >= 4.0 - 1e-4)


def test_trap_refuses_a_goal_margin_that_would_undo_gnron():
    with pytest.raises(ConfigError, match=r"scenario\.trap\.goal_margin = 1 exceeds goal_clearance"):
        family_params("trap", goal_margin=1.0)
    assert family_params("trap", goal_margin=1.0, kinds=["concave"]).goal_margin == 1.0


def test_endpoints_stay_clear_in_a_crowded_short_field():
    """Start and goal 3 m apart in a dense forest of spheres: obstacles get pushed, and those that
    cannot clear both ends are dropped."""
    p = family_params("clutter", distance=3.0, density=60.0, radius=(0.5, 1.5), shape="sphere",
                      start_margin=0.5, goal_margin=0.7)
    s = _batch(p)
    c = np.asarray(_endpoint_clearance(s, p.r_uav))
    assert np.all(c[:, 0] >= p.start_margin) and np.all(c[:, 1] >= p.goal_margin)
    assert np.all(~s.obstacles.cylinder)
    assert np.any(~s.obstacles.valid)
    assert np.all(s.obstacles.position[~s.obstacles.valid] == 1e6)


def test_clear_endpoints_by_hand():
    start, goal = jnp.array([0.0, 0.0, 2.0]), jnp.array([10.0, 0.0, 2.0])
    obstacles = Obstacles(
        position=jnp.array([[0.0, 0.0, 5.0],  # cylinder centred on the start (z ignored)
                            [9.5, 0.0, 2.0],  # sphere just short of the goal
                            [5.0, 3.0, 2.0],  # far from both: untouched
                            [5.0, 0.0, 2.0],  # invalid: untouched, parked
                            ]),
        velocity=jnp.zeros((4, 3)),
        radius=jnp.array([1.0, 0.5, 1.0, 9.0]),
        cylinder=jnp.array([True, False, True, True]),
        valid=jnp.array([True, True, True, False]),
    )
    out = jax.device_get(_clear(obstacles, start, goal, 0.3, 0.25, 0.25))
    # pushed perpendicular to the start-goal line (to its left) to clearance margin (+1 mm)
    np.testing.assert_allclose(out.position[0], [0.0, 1.0 + 0.3 + 0.25 + 1e-3, 5.0], atol=1e-5)
    # pushed radially away from the goal, back toward the start
    np.testing.assert_allclose(out.position[1], [10.0 - (0.5 + 0.3 + 0.25 + 1e-3), 0.0, 2.0], atol=1e-5)
    np.testing.assert_array_equal(out.position[2], [5.0, 3.0, 2.0])
    np.testing.assert_array_equal(out.position[3], [1e6, 1e6, 1e6])
    np.testing.assert_array_equal(out.valid, [True, True, True, False])

    # start and goal 2 m apart, an obstacle on the line between them that needs 1.05 m from both:
    # pushed back and forth, it cannot clear both ends, so it is dropped; the others stay
    squeezed = dataclasses.replace(obstacles, position=obstacles.position.at[0].set([0.5, 0.0, 2.0]),
                                   radius=obstacles.radius.at[0].set(0.5))
    out = jax.device_get(_clear(squeezed, start, jnp.array([2.0, 0.0, 2.0]), 0.3, 0.25, 0.25))
    assert not out.valid[0] and out.radius[0] == 0 and np.all(out.position[0] == 1e6)
    np.testing.assert_array_equal(out.valid, [False, True, True, False])


# --------------------------------------------------------------------------------------------
# keys and batching
# --------------------------------------------------------------------------------------------


def _leaves(s):
    return [np.asarray(x) for x in jax.tree.leaves(s)]


def test_determinism_field_independence_and_chunks():
    p = DEFAULTS["dynamic"]
    full = _leaves(make_scenarios(7, p, N))
    for a, b in zip(full, _leaves(make_scenarios(7, p, np.arange(N)))):
        np.testing.assert_array_equal(a, b)
    goal, position = full[1], full[2]
    assert not np.array_equal(goal[0], goal[1]) and not np.array_equal(position[2], position[3])
    assert not np.array_equal(np.asarray(make_scenarios(8, p, N).goal), goal)
    # a chunk of a sweep gives exactly the fields of the whole sweep
    later = _leaves(make_scenarios(7, p, jnp.arange(N, 2 * N)))
    middle = _leaves(make_scenarios(7, p, jnp.arange(N // 2, N // 2 + N)))
    for a, b, c in zip(middle, full, later):
        np.testing.assert_array_equal(a, np.concatenate([b[N // 2:], c[: N // 2]]))
    # field i is make_scenario(field_key(seed, i), params), bit for bit
    keys = jnp.stack([field_key(7, i) for i in range(N)])
    for a, b in zip(_leaves(jax.jit(jax.vmap(make_scenario, in_axes=(0, None)), static_argnums=1)(keys, p)), full):
        np.testing.assert_array_equal(a, b)


def test_make_scenarios_under_jit():
    p = DEFAULTS["overtake"]
    jitted = jax.jit(make_scenarios, static_argnums=1)(jnp.asarray(3), p, jnp.arange(N))
    for a, b in zip(_leaves(jitted), _leaves(make_scenarios(3, p, N))):
        np.testing.assert_array_equal(a, b)


def test_float64_under_x64():
    with jax.enable_x64(True):
        s = make_scenarios(0, DEFAULTS["crossing"], N)
        assert s.start.dtype == s.obstacles.position.dtype == s.obstacles.radius.dtype == jnp.float64
        assert np.all(np.asarray(_endpoint_clearance(s, 0.3)) >= 0.25)


# --------------------------------------------------------------------------------------------
# family geometry
# --------------------------------------------------------------------------------------------


def test_paper_static_is_a_fixed_closed_cup():
    p = DEFAULTS["paper_static"]
    s = _batch(p)
    np.testing.assert_array_equal(s.start, np.tile([0.0, 0.0, 2.0], (N, 1)))
    np.testing.assert_array_equal(s.goal, np.tile([24.0, 0.0, 2.0], (N, 1)))
    for leaf in _leaves(dataclasses.replace(s, key=None)):  # no jitter: all but the field key alike
        assert np.all(leaf == leaf[:1])
    xy = s.obstacles.position[0, :, :2]
    angles = np.linspace(-np.pi / 2, np.pi / 2, 5)
    np.testing.assert_allclose(xy, np.stack([10.5 + 3 * np.cos(angles), 3 * np.sin(angles)], -1), atol=1e-5)
    gaps = np.linalg.norm(np.diff(xy, axis=0), axis=1) - 2 * p.radius
    assert np.all(gaps < 2 * p.r_uav)  # too narrow for the UAV: the cup is closed

    jittered = _batch(family_params("paper_static", jitter=0.2))
    shift = jittered.obstacles.position - s.obstacles.position
    assert np.all(np.abs(shift) <= 0.2 + 1e-5) and not np.array_equal(shift[0], shift[1])


def test_paper_dynamic_is_a_long_diagonal_run_with_some_movers():
    p = DEFAULTS["paper_dynamic"]
    s = _batch(p)
    np.testing.assert_allclose(s.goal, np.tile([35 * math.sqrt(2), 35 * math.sqrt(2), 2.0], (N, 1)), rtol=1e-6)
    o = s.obstacles
    assert np.all(o.valid.sum(axis=1) == p.count)
    speed = np.linalg.norm(o.velocity, axis=-1)
    assert np.all(speed[:, : p.n_moving] >= p.speed[0] - 1e-6) and np.all(speed[:, : p.n_moving] <= p.speed[1] + 1e-6)
    assert np.all(speed[:, p.n_moving:] == 0)


def test_clutter_is_static_and_dynamic_moves():
    for family in ("clutter", "dynamic"):
        p = DEFAULTS[family]
        s = _batch(p)
        _, _, length = _frame(s)
        expected = np.minimum(np.round(p.density * length * p.width / 100), p.max_obstacles)
        np.testing.assert_array_equal(s.obstacles.valid.sum(axis=1), expected)
        along, lateral, _, _ = _local(s)
        valid = s.obstacles.valid
        assert np.all(np.abs(lateral[valid]) <= p.width / 2 + 1.0)  # + room for endpoint pushes
        speed = np.linalg.norm(s.obstacles.velocity, axis=-1)[valid]
        if family == "clutter":
            assert np.all(speed == 0)
        else:
            assert np.all((speed >= p.speed[0] - 1e-6) & (speed <= p.speed[1] + 1e-6))


def test_crossing_obstacles_cross_the_path_perpendicularly():
    p = DEFAULTS["crossing"]
    s = _batch(p)
    along, lateral, v_along, v_lateral = _local(s)
    valid = s.obstacles.valid
    _, _, length = _frame(s)
    speed = np.hypot(v_along, v_lateral)
    assert np.all(np.abs(v_along[valid]) <= 1e-5 * speed[valid])  # perpendicular to the line
    assert np.all((speed[valid] >= p.speed[0] - 1e-5) & (speed[valid] <= p.speed[1] + 1e-5))
    assert np.all(lateral[valid] * v_lateral[valid] < 0)  # heading toward the line
    frac = (along / length[:, None])[valid]
    assert np.all((frac >= p.meet[0] - 1e-5) & (frac <= p.meet[1] + 1e-5))
    # reaches the line when a UAV at uav_speed would, within the timing window
    offset = -lateral[valid] / v_lateral[valid] - along[valid] / p.uav_speed
    assert np.all((offset >= p.timing[0] - 1e-3) & (offset <= p.timing[1] + 1e-3))


def test_head_on_obstacles_come_toward_the_uav():
    p = DEFAULTS["head_on"]
    s = _batch(p)
    along, lateral, v_along, v_lateral = _local(s)
    valid = s.obstacles.valid
    _, _, length = _frame(s)
    assert np.all(v_along[valid] < 0) and np.allclose(v_lateral[valid], 0, atol=1e-5)
    assert np.all((-v_along[valid] >= p.speed[0] - 1e-5) & (-v_along[valid] <= p.speed[1] + 1e-5))
    assert np.all(np.abs(lateral[valid]) <= p.offset + 1e-5)
    frac = (along / length[:, None])[valid]
    assert np.all((frac >= p.along[0] - 1e-5) & (frac <= p.along[1] + 1e-5))


def test_overtake_obstacles_come_from_behind_faster_than_the_uav():
    p = DEFAULTS["overtake"]
    s = _batch(p)
    along, lateral, v_along, v_lateral = _local(s)
    valid = s.obstacles.valid
    assert np.all(along[valid] < 0)
    assert np.all((-along[valid] >= p.behind[0] - 1e-5) & (-along[valid] <= p.behind[1] + 1e-5))
    assert np.all(v_along[valid] > 2.0) and np.allclose(v_lateral[valid], 0, atol=1e-5)
    assert np.all(np.abs(lateral[valid]) <= p.offset + 1e-5)


@pytest.fixture(scope="module")
def trap_by_kind():
    return {k: _batch(family_params("trap", kinds=(k,))) for k in TRAP_KINDS}


@pytest.mark.parametrize("family", FAMILIES.names())
def test_every_family_names_its_kinds_and_every_field_has_one(family):
    kinds = FAMILIES.get(family).kinds
    assert kinds and all(isinstance(k, str) and k for k in kinds)
    index = np.asarray(make_scenarios(0, DEFAULTS[family], np.arange(64)).kind)
    assert index.shape == (64,) and np.all((index >= 0) & (index < len(kinds)))
    if len(kinds) > 1:
        assert set(index.tolist()) == set(range(len(kinds)))  # 64 draws see every kind


def test_a_trap_fields_kind_is_the_kind_its_geometry_was_built_as():
    batch = make_scenarios(3, DEFAULTS["trap"], np.arange(64))
    index, valid = np.asarray(batch.kind), np.asarray(batch.obstacles.valid).sum(axis=1)
    sizes = {"on_line": 1, "concave": 5, "narrow_gap": 2, "gnron": 1}
    assert all(valid[i] == sizes[TRAP_KINDS[k]] for i, k in enumerate(index))
    for kind in TRAP_KINDS:  # and a single-kind trap draws exactly its geometry and index
        only = make_scenarios(3, family_params("trap", kinds=(kind,)), np.arange(8))
        assert set(np.asarray(only.kind).tolist()) == {TRAP_KINDS.index(kind)}


def test_a_leaky_cup_has_the_closed_cups_centres_and_gaps_of_the_stated_width(trap_by_kind):
    leaky = _batch(family_params("trap", kinds=("concave",), cup_fill=0.3)).obstacles
    closed = trap_by_kind["concave"].obstacles
    np.testing.assert_allclose(leaky.position, closed.position, atol=1e-5)
    np.testing.assert_allclose(leaky.radius, 0.3 * closed.radius, rtol=1e-5)
    gaps = np.linalg.norm(np.diff(leaky.position, axis=1), axis=-1) - leaky.radius[:, 1:] - leaky.radius[:, :-1]
    np.testing.assert_allclose(gaps, 2 * 0.7 * closed.radius[:, 1:], rtol=1e-4, atol=1e-4)
    with pytest.raises(ConfigError, match=r"scenario\.trap\.cup_fill = 0"):
        family_params("trap", cup_fill=0.0)


def test_trap_kinds(trap_by_kind):
    p = DEFAULTS["trap"]
    counts = {"on_line": 1, "concave": 5, "narrow_gap": 2, "gnron": 1}
    for kind, s in trap_by_kind.items():
        assert np.all(s.obstacles.valid.sum(axis=1) == counts[kind]), kind
        c = np.asarray(_endpoint_clearance(s, p.r_uav))
        assert np.all(c[:, 0] >= p.start_margin - 1e-5) and np.all(c[:, 1] >= p.goal_margin - 1e-5), kind
    _, _, length = _frame(trap_by_kind["on_line"])
    along, lateral, _, _ = _local(trap_by_kind["on_line"])
    assert np.all(np.abs(lateral[:, 0]) <= p.offset + 1e-5)  # on the line, within the small offset
    assert np.all((along[:, 0] >= p.along[0] * length - 1e-4) & (along[:, 0] <= p.along[1] * length + 1e-4))

    gap = trap_by_kind["narrow_gap"].obstacles
    surface_gap = np.linalg.norm(gap.position[:, 0] - gap.position[:, 1], axis=-1) - gap.radius.sum(axis=1)
    assert np.all(surface_gap >= 2 * p.r_uav + p.gap_slack[0] - 1e-4)
    assert np.all(surface_gap <= 2 * p.r_uav + p.gap_slack[1] + 1e-4)

    gnron = trap_by_kind["gnron"]
    goal_clearance = np.asarray(_endpoint_clearance(gnron, p.r_uav))[:, 1, 0]
    assert np.all((goal_clearance >= p.goal_clearance[0] - 1e-4) & (goal_clearance <= p.goal_clearance[1] + 1e-4))

    cup = trap_by_kind["concave"].obstacles
    neighbours = np.linalg.norm(np.diff(cup.position, axis=1), axis=-1) - cup.radius[:, 1:] - cup.radius[:, :-1]
    np.testing.assert_allclose(neighbours, 0.0, atol=1e-4)  # touching: the cup is closed


def test_every_trap_field_is_one_of_the_single_kind_fields(trap_by_kind):
    mixed = _batch(DEFAULTS["trap"])
    seen = set()
    for f in range(N):
        matches = [k for k, s in trap_by_kind.items()
                   if all(np.array_equal(a[f], b[f]) for a, b in zip(_leaves(mixed), _leaves(s)))]
        assert len(matches) == 1
        seen.add(matches[0])
    assert len(seen) >= 2


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "family,overrides,message",
    [
        ("trap", dict(max_obstacles=0),
         r"scenario\.trap\.max_obstacles = 0 is out of range; allowed: an integer >= 1"),
        ("clutter", dict(max_obstacles=2.5), r"scenario\.clutter\.max_obstacles = 2\.5 must be an integer"),
        ("clutter", dict(density=-1.0),
         r"scenario\.clutter\.density = -1\.0 is out of range; allowed: a finite number >= 0"),
        ("clutter", dict(distance=0.0), r"scenario\.clutter\.distance = 0\.0 .*> 0"),
        ("clutter", dict(radius=(0.5, 1.0, 2.0)), r"scenario\.clutter\.radius .* a pair"),
        ("head_on", dict(speed=(2.0, 1.0)), r"scenario\.head_on\.speed = \(2\.0, 1\.0\) is not an interval"),
        ("dynamic", dict(speed=(-1.0, 1.0)), r"scenario\.dynamic\.speed = -1\.0"),
        ("overtake", dict(r_uav=-0.1), r"scenario\.overtake\.r_uav = -0\.1"),
        ("crossing", dict(goal_margin=-0.1), r"scenario\.crossing\.goal_margin = -0\.1"),
        ("crossing", dict(t_max=0.0), r"scenario\.crossing\.t_max = 0\.0 .*> 0"),
        ("crossing", dict(count=(1, 5)),
         r"scenario\.crossing\.count = 5 is out of range; allowed: an integer >= 1 and <= 3"),
        ("crossing", dict(count=(0, 2)), r"scenario\.crossing\.count = 0 .*>= 1"),
        ("clutter", dict(shape="cube"),
         r"scenario\.clutter\.shape = 'cube' is not allowed; choose one of cylinder, sphere"),
        ("clutter", dict(heading=(0.0, 400.0)), r"scenario\.clutter\.heading = 400\.0"),
        ("paper_static", dict(max_obstacles=3), r"scenario\.paper_static\.max_obstacles = 3 .*>= 5"),
        ("paper_static", dict(jitter=-0.1), r"scenario\.paper_static\.jitter = -0\.1"),
        ("paper_dynamic", dict(count=20), r"scenario\.paper_dynamic\.count = 20 .*<= 16"),
        ("paper_dynamic", dict(n_moving=15), r"scenario\.paper_dynamic\.n_moving = 15 .*<= 14"),
        ("trap", dict(kinds=("on_line", "spiral")),
         r"scenario\.trap\.kinds\[1\] = 'spiral' is not a kind; allowed: on_line, concave, narrow_gap, gnron"),
        ("trap", dict(kinds=3), r"scenario\.trap\.kinds = 3 is not a kind"),
        ("trap", dict(kinds=()), r"scenario\.trap\.kinds = \(\) must list one or more of on_line"),
        ("trap", dict(kinds=("gnron", "gnron")), r"scenario\.trap\.kinds .* lists a kind twice"),
        ("trap", dict(kinds=("concave",), max_obstacles=3), r"scenario\.trap\.max_obstacles = 3 .*>= 5"),
        ("trap", dict(along=(0.5, 1.5)), r"scenario\.trap\.along = 1\.5 .*<= 1"),
        ("clutter", dict(bogus=1),
         r"scenario\.clutter\.bogus is not a parameter of clutter; allowed: max_obstacles, r_uav"),
    ],
)
def test_bad_params(family, overrides, message):
    with pytest.raises(ConfigError, match=message):
        family_params(family, **overrides)


def test_unknown_family_lists_the_families():
    with pytest.raises(ConfigError, match=r"scenario\.family = 'spiral' is not a registered family; "
                                          r"choose one of paper_static, "
                                          r"paper_dynamic, trap, clutter, crossing, head_on, overtake, dynamic"):
        family_params("spiral")


def test_bad_field_selection():
    with pytest.raises(ConfigError, match=r"scenario\.fields = -1"):
        make_scenarios(0, DEFAULTS["trap"], -1)
    with pytest.raises(ConfigError, match=r"scenario\.fields must be .* 1-D integer array"):
        make_scenarios(0, DEFAULTS["trap"], np.zeros((2, 2), np.int32))
    with pytest.raises(ConfigError, match=r"scenario\.fields must be"):
        make_scenarios(0, DEFAULTS["trap"], np.array([0.5]))


def test_values_are_normalised_and_hashable():
    p = family_params("trap", kinds=["gnron", "on_line"], distance=25, radius=[1, 1.2], max_obstacles=np.int64(2))
    assert p.kinds == ("on_line", "gnron")  # canonical order
    assert p.distance == (25.0, 25.0) and p.radius == (1.0, 1.2) and type(p.max_obstacles) is int
    assert family_params("trap", kinds="gnron", max_obstacles=1).kinds == ("gnron",)
    assert p == family_params("trap", kinds=("on_line", "gnron"), distance=(25.0, 25.0), radius=(1.0, 1.2),
                              max_obstacles=2)
    assert len({p, family_params("trap", kinds=("gnron", "on_line"), distance=25, radius=(1, 1.2),
                                 max_obstacles=2)}) == 1
    assert family_params("clutter") != family_params("dynamic", speed=(0.0, 0.0))


def test_simulate_flies_the_first_field_of_a_familys_defining_kind():
    """trap's fields at seed 0 are on_line, narrow_gap, concave, ...: the first concave cup is field 2; a family
    of one kind keeps field 0; a defining kind the family does not draw is refused."""

    from jaxapf.scenarios import FAMILIES, Family, make_scenarios
    from jaxapf.simulate.episodes import defining_field
    from jaxapf.validation import ConfigError

    trap = FAMILIES.get("trap")
    kinds = np.asarray(make_scenarios(0, family_params("trap"), 3).kind)
    assert trap.defining == "concave" and [trap.kinds[k] for k in kinds] == ["on_line", "narrow_gap", "concave"]
    assert defining_field("trap", 0) == 2 and defining_field("clutter", 0) == 0
    assert FAMILIES.get("clutter").defining == "clutter"
    with pytest.raises(ConfigError, match="defining kind 'cup' is not one of its kinds"):
        Family(trap.params, trap.build, trap.kinds, "", "cup")


@pytest.mark.slow
def test_simulate_names_the_field_it_chose_and_its_kind(tmp_path, capsys):
    from jaxapf.cli import main

    assert main(["simulate", "--family", "trap", "--t-max", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr()
    assert "note: field 2 is the first concave field of trap at seed 0" in out.out
    assert "trap (seed 0, field 2, concave)" in out.out
    assert "simulate trap: 0/2 method (0 %)" in out.err  # a line before the first method compiles

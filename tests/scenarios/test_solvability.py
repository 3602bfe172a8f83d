"""The solvability oracle on hand-made fields whose answer is known, and on every built-in family.

Hand-made fields fly at z = 2 m from (0, 0) to (20, 0) with the engine's UAV (r_uav 0.3 m, v_max
2 m/s). Walls are rows of cylinders of radius 0.5 m, 0.8 m apart (neighbours overlap by 0.2 m).
"""

import dataclasses

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.datatypes import Obstacles, Scenario
from jaxapf.scenarios import FAMILIES, family_params, make_scenarios, reach_cell, solvable
from jaxapf.validation import ConfigError

Z = 2.0
START, GOAL = (0.0, 0.0, Z), (20.0, 0.0, Z)


@dataclasses.dataclass
class Ob:
    """One obstacle: centre, radius, shape, velocity."""

    x: float
    y: float
    radius: float = 0.5
    z: float = Z
    cylinder: bool = True
    v: tuple = (0.0, 0.0, 0.0)


def field(*obstacles: Ob, start=START, goal=GOAL, slots: int = 0) -> Scenario:
    """A field of numpy leaves, no batch axis: the obstacles, then padded slots (at least one, up
    to ``slots`` in all)."""
    rows = list(obstacles)
    pad = max(slots - len(rows), 1)
    position = np.array([[o.x, o.y, o.z] for o in rows] + [[1e6, 1e6, 1e6]] * pad, np.float32).reshape(-1, 3)
    velocity = np.array([o.v for o in rows] + [(0.0, 0.0, 0.0)] * pad, np.float32).reshape(-1, 3)
    return Scenario(
        start=np.array(start, np.float32),
        goal=np.array(goal, np.float32),
        obstacles=Obstacles(
            position=position,
            velocity=velocity,
            radius=np.array([o.radius for o in rows] + [0.0] * pad, np.float32),
            cylinder=np.array([o.cylinder for o in rows] + [False] * pad, bool),
            valid=np.array([True] * len(rows) + [False] * pad, bool),
        ),
    )


def wall(lo: float, hi: float, x: float = 10.0, **kwargs) -> list[Ob]:
    """Overlapping cylinders (radius 0.5 m, centres 0.8 m apart) along y from ``lo`` to ``hi``."""
    return [Ob(x, y, **kwargs) for y in np.arange(lo, hi + 1e-9, 0.8)]


def gap_wall(width: float, reach: float = 25.0) -> list[Ob]:
    """A wall across the line at x = 10 out to ``±reach`` with one gap of ``width`` between the
    surfaces of the two cylinders either side of the line."""
    first = 0.5 * width + 0.5
    side = [first + 0.8 * i for i in range(int((reach - first) / 0.8) + 1)]
    return [Ob(10.0, s * y) for s in (1.0, -1.0) for y in side]


UAV = {"r_uav": 0.3, "v_max": 2.0, "t_max": 60.0}


def answer(scenario: Scenario, **kwargs) -> bool:
    """The oracle's answer for one field, with the engine's UAV and a 60 s episode by default; the same as the
    search's own (``certify=False``: the oracle of 360a044, without the certificates that answer most fields
    before the search), float64."""
    out = solvable(scenario, **(UAV | kwargs))
    assert out.shape == () and out.dtype == bool
    assert out == solvable(scenario, **(UAV | kwargs), certify=False)
    return bool(out)


# ------------------------------------------------------------------------------------------
# static fields
# ------------------------------------------------------------------------------------------


def test_an_empty_field_is_solvable():
    assert answer(field())


def test_a_wall_across_the_corridor_and_beyond_is_unsolvable():
    # out to ±25 m: flying around its end takes more than t_max = 20 s at 2 m/s per axis
    assert not answer(field(*wall(-25.0, 25.0)), t_max=20.0)


def test_a_finite_wall_can_be_flown_around_when_there_is_time():
    assert answer(field(*wall(-25.0, 25.0)), t_max=60.0)
    assert answer(field(*wall(-5.0, 5.0)), t_max=20.0)


@pytest.mark.parametrize("spare, expected", [(0.1, True), (-0.1, False)])
def test_a_gap_a_little_wider_than_the_uav_is_open_and_a_little_narrower_is_closed(spare, expected):
    # surfaces 2 r_uav ± 0.1 m apart: 0.05 m to spare or missing on each side, 2 cells of 0.025 m
    assert answer(field(*gap_wall(0.6 + spare)), t_max=20.0) is expected


def test_a_gap_one_cell_wider_than_the_uav_is_open():
    # the gap between surfaces is the UAV's diameter and one cell of the static grid (0.025 m)
    assert answer(field(*gap_wall(2 * UAV["r_uav"] + 0.025)))


def test_a_mover_that_seals_a_corridor_delays_the_uav():
    # a corridor between walls along y = ±2.1 m (x from 2 to 18 m); a cylinder of radius 1.6 m crossing it at
    # x = 10 m at 3.2 m/s, on the line at t = 5 s, when the UAV flying at v_max would pass: it seals the
    # corridor for about a second and the UAV arrives about 0.6 s later than in the empty corridor
    walls = [Ob(x, s * 2.1, radius=0.6) for x in np.arange(2.0, 18.01, 0.8) for s in (1.0, -1.0)]
    mover = Ob(10.0, -16.0, radius=1.6, v=(0.0, 3.2, 0.0))
    assert answer(field(*walls), t_max=10.0)
    assert not answer(field(*walls, mover), t_max=10.0)
    assert answer(field(*walls, mover), t_max=10.6)


def test_the_gap_decides_at_a_coarser_resolution_too():
    # h = 0.05 m: a passage narrower than the UAV by more than sqrt 2 h ~ 0.07 m stays closed
    assert answer(field(*gap_wall(0.75)), t_max=20.0, resolution=0.05)
    assert not answer(field(*gap_wall(0.45)), t_max=20.0, resolution=0.05)


def test_a_closed_ring_around_the_goal_is_unsolvable():
    phi = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)  # centres 0.98 m apart, radius 0.6 m
    ring = [Ob(20.0 + 2.5 * np.cos(a), 2.5 * np.sin(a), radius=0.6) for a in phi]
    assert not answer(field(*ring))
    assert answer(field(*ring[1:]))  # one cylinder missing: a 1.8 m doorway


def test_the_papers_closed_cup_can_be_flown_around():
    p = family_params("paper_static")
    assert bool(solvable(make_scenarios(0, p, 1), r_uav=p.r_uav, v_max=2.0, t_max=p.t_max)[0])


def test_a_cup_closed_on_every_side_is_unsolvable():
    phi = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)  # the paper's spacing, all the way round
    cup = [Ob(20.0 + 3.0 * np.cos(a), 3.0 * np.sin(a), radius=1.0) for a in phi]
    assert not answer(field(*cup))


def test_start_or_goal_inside_an_obstacle_is_unsolvable():
    assert not answer(field(Ob(20.0, 0.0, radius=1.0)))
    assert not answer(field(Ob(20.4, 0.0, radius=0.5)))  # the UAV at the goal would touch it
    assert not answer(field(Ob(0.0, 0.3, radius=0.5)))


@pytest.mark.parametrize("dz, expected", [
    (0.0, False),   # a wall of spheres in the plane
    (0.5, False),   # cut by the plane: blocked discs of radius sqrt(0.8^2 - 0.5^2) = 0.62 m overlap
    (0.6, False),   # the plane misses the sphere (0.6 > 0.5) but the UAV (r_uav 0.3) would touch it
    (0.79, True),   # blocked discs of radius 0.13 m, 0.8 m apart: the UAV passes between them
    (1.0, True),    # out of the UAV's reach
    (10.0, True),   # far above the plane: absent
])
def test_spheres_block_the_plane_where_the_uav_would_touch_them(dz, expected):
    spheres = wall(-25.0, 25.0, z=Z + dz, cylinder=False)
    assert answer(field(*spheres), t_max=20.0) is expected


def test_a_goal_at_another_height_is_projected_onto_the_plane():
    assert answer(field(goal=(20.0, 0.0, 5.0)))
    assert not answer(field(*wall(-25.0, 25.0), goal=(20.0, 0.0, 5.0)), t_max=20.0)
    assert not answer(field(goal=(20.0, 0.0, 50.0)), t_max=20.0)  # 48 m of climb: beyond 2 m/s · 20 s


# ------------------------------------------------------------------------------------------
# moving fields
# ------------------------------------------------------------------------------------------


def test_a_moving_wall_that_sweeps_past_can_be_waited_out_but_not_in_a_short_episode():
    # a 40 m wall across the line from y = -30 to 10, sliding along itself (+y) at 1.5 m/s: its lower
    # end crosses the line at t = 20 s, so the goal can be reached after about 25 s and not by 12 s
    sweep = field(*wall(-30.0, 10.0, v=(0.0, 1.5, 0.0)))
    assert answer(sweep, t_max=60.0)
    assert not answer(sweep, t_max=12.0)


def test_a_wall_that_never_leaves_is_unsolvable():
    # the same wall sliding across the line without end, within the episode
    assert not answer(field(*wall(-100.0, 10.0, v=(0.0, 1.5, 0.0))), t_max=30.0)


def test_a_wall_of_spheres_that_rises_out_of_the_plane_can_be_waited_out():
    # in the plane at t = 0 (closed, see above) and rising at 0.1 m/s: the blocked discs part
    # (radius sqrt(0.8^2 - dz^2) < 0.4 m) at dz = 0.69 m, t = 6.9 s, so the UAV cannot be at the goal,
    # 10 m beyond, before 11.9 s, although the straight flight takes 10 s
    rising = wall(-25.0, 25.0, cylinder=False, v=(0.0, 0.0, 0.1))
    assert answer(field(*rising), t_max=20.0)
    assert not answer(field(*rising), t_max=10.5)
    assert answer(field(), t_max=10.5)


def test_a_head_on_mover_in_an_empty_corridor_is_solvable():
    assert answer(field(Ob(15.0, 0.0, radius=1.0, v=(-1.5, 0.0, 0.0))))


def test_a_mover_over_the_goal_only_delays_the_arrival():
    leaving = field(Ob(20.0, 0.0, radius=1.0, v=(0.0, 0.5, 0.0)))
    assert answer(leaving)
    assert not answer(field(Ob(20.0, 0.0, radius=1.0)))


def test_a_mover_that_keeps_the_uav_shut_in_is_unsolvable_until_it_leaves():
    # a closed ring around the start whose cylinder at +x drifts outward at 0.01 m/s: the doorway
    # lets the UAV out only after about two minutes
    phi = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)  # centres 0.98 m apart, radius 0.6 m
    ring = [Ob(2.5 * np.cos(a), 2.5 * np.sin(a), radius=0.6) for a in phi[1:]]
    door = Ob(2.5, 0.0, radius=0.6, v=(0.01, 0.0, 0.0))
    assert not answer(field(*ring, door), t_max=60.0)
    assert answer(field(*ring, door), t_max=400.0)
    assert answer(field(*ring))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(3.0, 17.0), st.floats(-4.0, 4.0), st.floats(0.3, 2.0), st.floats(-2.0, 2.0),
                          st.floats(-2.0, 2.0), st.booleans()), min_size=1, max_size=12),
       st.floats(8.0, 40.0))
def test_the_certificates_never_change_an_answer(obstacles, t_max):
    """Random fields of up to twelve obstacles across the line, still or moving (a moving field takes the
    reachability's flights, a still one the static test's blocks): the search's answer whatever the
    certificates found."""
    rows = [Ob(x, y, radius=r, v=(vx, vy, 0.0) if moves else (0.0, 0.0, 0.0)) for x, y, r, vx, vy, moves in obstacles]
    answer(field(*rows), t_max=t_max)


# ------------------------------------------------------------------------------------------
# batches, arguments, built-in families
# ------------------------------------------------------------------------------------------


def test_a_batch_gives_one_answer_per_field_in_its_shape():
    fields = [field(slots=2), field(Ob(20.0, 0.0, radius=1.0), slots=2),
              field(Ob(15.0, 0.0, radius=1.0, v=(-1.5, 0.0, 0.0)), slots=2)]
    batch = jax.tree.map(lambda *a: np.stack(a).reshape((3, 1) + a[0].shape), *fields)
    out = solvable(batch, **UAV)
    assert out.shape == (3, 1) and out.dtype == bool
    assert out[:, 0].tolist() == [True, False, True]


@pytest.mark.parametrize("name, value", [("resolution", 0.0), ("v_max", -1.0), ("t_max", float("nan")),
                                         ("r_uav", -0.1), ("margin", -1.0)])
def test_arguments_out_of_range_are_rejected(name, value):
    with pytest.raises(ConfigError, match=f"solvable.{name}"):
        solvable(field(), **(UAV | {name: value}))


def test_the_reachability_grid_coarsens_only_for_large_boxes():
    # a 30 m run at 45 degrees with 5 m margins and t_max 60 s keeps 0.1 m; paper_dynamic's 70 m run
    # at 45 degrees over 300 s gets about 0.24 m
    side = 30.0 / np.sqrt(2.0) + 10.0
    assert reach_cell(side * side, v_max=2.0, t_max=60.0) == pytest.approx(0.1)
    side = 70.0 / np.sqrt(2.0) + 10.0
    assert reach_cell(side * side, v_max=2.0, t_max=300.0) == pytest.approx(0.242, abs=0.005)


_FIELDS = 64


@pytest.fixture(scope="module")
def family_answers():
    """Every built-in family, 64 fields of seed 0 at its default parameters and recommended t_max."""
    out = {}
    for name in FAMILIES:
        p = family_params(name)
        batch = jax.device_get(make_scenarios(0, p, _FIELDS))
        out[name] = (batch, p, solvable(batch, r_uav=p.r_uav, v_max=2.0, t_max=p.t_max))
    return out


@pytest.mark.slow
def test_the_certificates_answer_as_the_search_does_on_every_family(family_answers):
    """A certificate (a free path of whole blocks, a flight through the reachable sets) only ever says
    solvable where the search would: on 64 fields of every family the answers are the search's alone
    (benchmarks/oracle.py checks 8,192 fields of every family, single-UAV and swarm)."""
    for name, (batch, p, answers) in family_answers.items():
        np.testing.assert_array_equal(answers, solvable(batch, r_uav=p.r_uav, v_max=2.0, t_max=p.t_max,
                                                        certify=False), err_msg=name)


@pytest.mark.slow
def test_every_built_in_family_gets_an_answer_per_field(family_answers):
    for name, (_, _, answers) in family_answers.items():
        assert answers.shape == (_FIELDS,) and answers.dtype == bool, name
        assert np.isfinite(answers.mean()) and 0.0 <= answers.mean() <= 1.0, name


def test_families_whose_fields_are_solvable_by_construction(family_answers):
    # paper_static: the cup is closed, but open toward the start and free behind: fly around it.
    # head_on, overtake: 1-2 movers of radius <= 1 m in a corridor the UAV can leave sideways.
    for name in ("paper_static", "head_on", "overtake"):
        assert family_answers[name][2].all(), name
    # clutter fields are almost all solvable (7 % of the corridor covered)
    assert family_answers["clutter"][2].mean() >= 0.9


@pytest.mark.parametrize("kind", ["concave", "narrow_gap", "on_line"])
def test_trap_kinds_that_can_be_flown_around_are_solvable(kind):
    # concave cups are closed but open toward the start; a narrow gap leaves 0.05-0.3 m a side
    p = family_params("trap", kinds=(kind,))
    assert solvable(make_scenarios(0, p, 16), r_uav=p.r_uav, v_max=2.0, t_max=p.t_max).all()


def test_the_answer_is_deterministic(family_answers):
    for name in ("trap", "crossing"):
        batch, p, answers = family_answers[name]
        again = solvable(jax.tree.map(lambda a: a[:16], batch), r_uav=p.r_uav, v_max=2.0, t_max=p.t_max)
        np.testing.assert_array_equal(again, answers[:16])

"""Swarm families (jaxapf.scenarios.swarms): geometry by construction, batch independence, one-line errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxapf.scenarios.swarms import SWARM_FAMILIES, make_swarms, swarm_params
from jaxapf.validation import ConfigError


def _np(swarm):
    return jax.tree_util.tree_map(np.asarray, swarm)


@pytest.mark.parametrize("family", SWARM_FAMILIES.names())
def test_a_field_is_the_same_in_any_batch_and_for_the_same_seed(family):
    params = swarm_params(family)
    batch, alone = _np(make_swarms(4, params, 6)), _np(make_swarms(4, params, jnp.array([5])))
    for a, b in zip(jax.tree_util.tree_leaves(batch), jax.tree_util.tree_leaves(alone)):
        np.testing.assert_array_equal(a[5], b[0])
    assert batch.start.shape == (6, params.agents, 3) and batch.valid.all()
    assert not np.array_equal(batch.start[0], batch.start[1])  # fields differ


@pytest.mark.parametrize("family", SWARM_FAMILIES.names())
def test_starts_are_apart_and_obstacles_keep_clear_of_every_start_and_goal(family):
    params = swarm_params(family)
    s = _np(make_swarms(0, params, 16))
    gaps = np.linalg.norm(s.start[:, :, None] - s.start[:, None], axis=-1) + 1e9 * np.eye(params.agents)
    assert gaps.min() > 2 * params.r_uav  # nobody starts inside another UAV
    assert np.allclose(s.start[..., 2], params.altitude) and np.allclose(s.goal[..., 2], params.altitude)
    for points, margin in ((s.start, params.start_margin), (s.goal, params.goal_margin)):
        d = np.linalg.norm((s.obstacles.position[:, :, None, :2] - points[:, None, :, :2]), axis=-1)
        clearance = d - s.obstacles.radius[..., None] - params.r_uav
        assert np.all(clearance[s.obstacles.valid] >= margin - 1e-5)


def test_circle_swap_flies_every_uav_to_the_antipodal_point():
    params = swarm_params("circle_swap", agents=12, jitter=0.0)
    s = _np(make_swarms(0, params, 8))
    radius = np.linalg.norm(s.start[..., :2], axis=-1)
    assert np.all((radius >= 0.5 * params.distance[0] - 1e-4) & (radius <= 0.5 * params.distance[1] + 1e-4))
    np.testing.assert_allclose(radius, radius[:, :1] * np.ones((1, 12)), rtol=1e-5)  # one circle per field
    np.testing.assert_allclose(s.goal[..., :2], -s.start[..., :2], atol=1e-5)
    angles = np.sort(np.mod(np.arctan2(s.start[..., 1], s.start[..., 0]), 2 * np.pi), axis=1)
    np.testing.assert_allclose(np.diff(angles, axis=1), 2 * np.pi / 12, atol=1e-4)  # evenly spaced
    assert not s.obstacles.valid.any()
    jittered = _np(make_swarms(0, swarm_params("circle_swap", agents=12), 8))
    assert 0 < np.abs(jittered.start - s.start).max() <= np.sqrt(2) * 0.1 + 1e-6


def test_crossing_flows_cross_at_right_angles_and_groups_divide_the_uavs():
    params = swarm_params("crossing_flows", agents=8, groups=4, jitter=0.0, heading=(0.0, 0.0))
    s = _np(make_swarms(0, params, 4))
    direction = s.goal[..., :2] - s.start[..., :2]
    length = np.linalg.norm(direction, axis=-1)
    np.testing.assert_allclose(length, length[:, :1] * np.ones((1, 8)), rtol=1e-5)
    unit = np.round(direction / length[..., None], 5)
    assert unit[0].tolist() == [[1, 0]] * 2 + [[0, 1]] * 2 + [[-1, 0]] * 2 + [[0, -1]] * 2
    with pytest.raises(ConfigError, match=r"scenario\.crossing_flows\.agents = 6 must be a multiple of groups = 4"):
        swarm_params("crossing_flows", agents=6, groups=4)


def test_formation_gap_opens_exactly_the_drawn_gap_in_a_closed_wall():
    params = swarm_params("formation_gap", heading=(0.0, 0.0), jitter=0.0)
    s = _np(make_swarms(0, params, 8))
    y = np.sort(s.obstacles.position[..., 1], axis=1)
    surface_gaps = np.diff(y, axis=1) - 2 * params.wall_radius
    widest = surface_gaps.max(axis=1)
    assert np.all((widest >= params.gap[0] - 1e-4) & (widest <= params.gap[1] + 1e-4))
    assert np.all(np.sort(surface_gaps, axis=1)[:, -2] < 2 * params.r_uav)  # elsewhere no UAV passes
    np.testing.assert_allclose(s.goal[..., 0] - s.start[..., 0], (s.goal[..., 0] - s.start[..., 0])[:, :1]
                               * np.ones((1, params.agents)), rtol=1e-5)  # the formation is kept
    with pytest.raises(ConfigError, match=r"gap = \[0\.5, 1\.0\] must be wider than the UAV"):
        swarm_params("formation_gap", gap=(0.5, 1.0))


def test_swarm_clutter_mirrors_the_goals_so_every_pair_of_paths_crosses():
    params = swarm_params("swarm_clutter", agents=6, heading=(0.0, 0.0), jitter=0.0)
    s = _np(make_swarms(0, params, 4))
    np.testing.assert_allclose(s.goal[:, :, 1], s.start[:, ::-1, 1], atol=1e-5)
    assert s.obstacles.valid.sum(axis=1).min() > 0 and np.any(np.abs(s.obstacles.velocity).sum(-1) > 0)


def test_bad_swarm_parameters_are_one_line_errors():
    with pytest.raises(ConfigError, match=r"scenario\.circle_swap\.agents = 0 is out of range"):
        swarm_params("circle_swap", agents=0)
    with pytest.raises(ConfigError, match=r"scenario\.circle_swap\.wind is not a parameter of circle_swap"):
        swarm_params("circle_swap", wind=1.0)
    with pytest.raises(ConfigError, match=r"'ring' is not a registered swarm family"):
        swarm_params("ring")


def test_the_oracle_answers_for_every_uav_alone():
    """Obstacle-free families and the formation's gap: every UAV solvable. By hand: a cylinder over one
    UAV's goal makes that UAV, and only it, unsolvable; a padded slot counts as solvable."""
    from jaxapf.datatypes import Obstacles
    from jaxapf.datatypes.swarm import Swarm
    from jaxapf.scenarios.swarms import agents_solvable

    oracle = dict(r_uav=0.3, v_max=2.0, t_max=40.0)
    free = make_swarms(0, swarm_params("circle_swap", agents=4), 2)
    assert agents_solvable(free, **oracle).shape == (2, 4) and agents_solvable(free, **oracle).all()
    assert agents_solvable(make_swarms(0, swarm_params("formation_gap", agents=4, columns=2), 2), **oracle).all()
    block = Obstacles(position=np.array([[10.0, 4.0, 2.0]]), velocity=np.zeros((1, 3)), radius=np.array([1.0]),
                      cylinder=np.array([True]), valid=np.array([True]))
    swarm = Swarm(start=np.array([[0.0, 0, 2], [0, 4, 2], [0, 8, 2]]), goal=np.array([[10.0, 0, 2], [10, 4, 2],
                                                                                       [10, 4, 2]]),
                  valid=np.array([True, True, False]), obstacles=block)
    assert agents_solvable(swarm, **oracle).tolist() == [True, False, True]


@pytest.mark.parametrize("family", ["circle_swap", "crossing_flows", "formation_gap", "swarm_clutter"])
@pytest.mark.parametrize("agents", [2, 8, 32, 64])
def test_no_two_uavs_start_or_end_inside_each_other(family, agents):
    """Every pair of starts and every pair of goals is at least 2 r_uav apart, jitter included: wide
    crossing flows push their square out and a crowded circle grows (32 UAVs in two crossing flows
    used to start inside each other in about half the fields)."""
    params = swarm_params(family, agents=agents, **({"columns": min(4, agents)} if family == "formation_gap" else {}))
    swarms = jax.device_get(make_swarms(300, params, 32))
    for points in (np.asarray(swarms.start), np.asarray(swarms.goal)):
        gap = np.linalg.norm(points[:, :, None] - points[:, None, :], axis=-1) + 1e9 * np.eye(agents)
        assert gap.min() >= 2 * params.r_uav

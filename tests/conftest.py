"""Fixtures shared across the test tree."""

from __future__ import annotations

import pathlib

import jax.numpy as jnp
import pytest

from jaxapf import Obstacles, Scenario

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo_root() -> pathlib.Path:
    """The repository's root (docs, sweeps, benchmarks, analysis)."""
    return ROOT


def three_obstacle_field(xp=jnp, dtype=None) -> Scenario:
    """3 real obstacles (a static sphere near the start–goal line, a cylinder, a moving sphere crossing
    the path) and one padded slot; float64 by default (create inside ``jax.enable_x64`` for JAX)."""
    f = lambda a: xp.asarray(a, dtype=dtype or xp.float64)
    return Scenario(
        start=f([0.0, 0.0, 0.0]),
        goal=f([12.0, 0.5, 0.5]),
        obstacles=Obstacles(
            position=f([[4.0, 0.3, 0.0], [7.0, -1.5, 5.0], [9.0, 4.0, 0.2], [1e6, 1e6, 1e6]]),
            velocity=f([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-0.3, -0.6, 0.0], [0.0, 0.0, 0.0]]),
            radius=f([1.0, 0.8, 0.7, 0.0]),
            cylinder=xp.asarray([False, True, False, False]),
            valid=xp.asarray([True, True, True, False]),
        ),
    )


@pytest.fixture
def field_factory():
    """:func:`three_obstacle_field`, as a fixture for tests outside its module's directory."""
    return three_obstacle_field


def one_obstacle_scenario(goal_x: float, obstacle_x: float, radius: float) -> Scenario:
    """Start at the origin (2 m up), the goal and one vertical cylinder on the x axis."""
    return Scenario(start=jnp.asarray([0.0, 0.0, 2.0]), goal=jnp.asarray([goal_x, 0.0, 2.0]),
                    obstacles=Obstacles(position=jnp.asarray([[obstacle_x, 0.0, 2.0]]), velocity=jnp.zeros((1, 3)),
                                        radius=jnp.asarray([radius]), cylinder=jnp.asarray([True]),
                                        valid=jnp.asarray([True])))


def outcomes(scenario: Scenario, methods, t_max: float = 40.0) -> dict[str, dict[str, bool]]:
    """success / collision / stalled of one episode per planner (default gains, N = 10, I = 20)."""
    import jax

    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.metrics import episode_metrics
    from jaxapf.rollout import rollout

    mpc, out = MPCConfig(horizon=10, iters=20), {}
    for method in methods:
        sim = SimConfig.from_flat(method=method, t_max=t_max)
        traj = jax.jit(rollout, static_argnums=(2, 3))(scenario, Gains(), sim, mpc)
        metrics = episode_metrics(traj, scenario, sim, ("success", "collision", "stalled"))
        out[method] = {k: bool(v) for k, v in metrics.items()}
    return out

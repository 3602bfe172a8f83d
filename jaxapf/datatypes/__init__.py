"""The data every part of the engine shares: obstacle fields, scenarios and trajectories.

Every class is a pytree whose leaves are arrays (MJX's rule), so any of them can be batched with
``vmap`` and passed through ``jit``.
"""

from .obstacles import ObstacleColumns, Obstacles, clearance, obstacles_at, project, safe_norm, segment_clearance
from .scenario import Scenario, episode_key
from .trajectory import Trajectory

__all__ = ["Obstacles", "ObstacleColumns", "Scenario", "Trajectory", "episode_key", "project", "safe_norm",
           "obstacles_at", "clearance", "segment_clearance"]

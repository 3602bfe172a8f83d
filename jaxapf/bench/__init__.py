"""``jaxapf bench``: how fast the engine is, against the peers a user would otherwise pick.

==================  ===============================================================
:mod:`.engine`      ``jaxapf bench engine``: the engine against the numpy + OSQP oracle
:mod:`.sweep`       ``jaxapf bench sweep``: the whole sweep path against bare engine calls
:mod:`.world`       ``jaxapf bench world``: sensing, wind and the quadrotor against the ideal world
:mod:`.oracle`      the numpy + OSQP implementation of the same closed loop
==================  ===============================================================

The maintainers' diagnostics (where a step's time goes, XLA options, kernel costs, the sweep's
cost model) are scripts in ``benchmarks/`` (``benchmarks/README.md``).
"""

from .engine import format_benchmark, run_benchmark
from .sweep import format_sweep_benchmark, run_sweep_benchmark
from .world import format_world_benchmark, run_world_benchmark

__all__ = ["run_benchmark", "format_benchmark", "run_sweep_benchmark", "format_sweep_benchmark",
           "run_world_benchmark", "format_world_benchmark"]

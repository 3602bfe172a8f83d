"""Study 17: the planners the field flies (MPPI, the keep-out MPC) against the paper's potential field.

``jaxapf compare sweeps/flown-planners.toml``: study 11's protocol (the same selection budget, seeds,
families, held-out fields and test seed, one verdict function, Holm) with ``mppi`` (sampling-based MPC)
and ``keepout_mpc`` (every obstacle a constraint at every horizon step) beside the paper's
``direction_velocity``, ``basic`` and study 11's leader ``velocity_obstacle``. Each setting is paired with
``basic`` of the same selection, and in a second report with ``direction_velocity``.

    python analysis/flown_planners.py     # ~1 h on 2 cores: selection, test sweep, two reports, figures
"""

from __future__ import annotations

import study
from planner_benchmark import run_benchmark


def main() -> None:
    run_benchmark(__doc__, "flown_planners", "flown-planners.toml",
                  "Study 17 — the planners the field flies against the paper's potential field")


if __name__ == "__main__":
    study.entry(main)

"""``jaxapf simulate``: one field, several planners side by side, trajectories and the paper's figures.

:mod:`.episodes` runs the planners on a field and writes the outputs; :mod:`.figures` draws the
paper's figures (section 4) from plain arrays (also used by the report's gallery).
"""

from .episodes import format_metrics_table, simulate_runs, write_outputs
from .figures import FIGURES, Field, Run, outcome, plot_all, plot_trajectories, run_colors

__all__ = ["simulate_runs", "write_outputs", "format_metrics_table", "Run", "Field", "FIGURES", "run_colors",
           "outcome", "plot_all", "plot_trajectories"]

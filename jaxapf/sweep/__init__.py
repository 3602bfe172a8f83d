r"""``jaxapf sweep``: run a study stated in a TOML spec, streaming metrics into a Parquet dataset.

A spec (:mod:`.spec`) expands into settings; settings with the same static part form a variant, one
compiled program whose gains are vmapped inside :func:`jaxapf.engine.evaluate`. The work is cut
into chunks, each a block of fields of one family × a variant's settings, one ``evaluate`` call per
device and one Parquet part (:mod:`.plan` variants, chunks and estimates; :mod:`.schema` the
layout; :mod:`.output` the output directory; :mod:`.run` the runner; :mod:`.execute` where chunks
run, :mod:`.cluster` as Ray tasks; :mod:`.read` reading back). An
episode's numbers do not depend on the chunking, the memory budget, the devices or what was
resumed. docs/sweep.md says how and why (variants, chunks, the memory estimate, devices,
determinism); docs/sweep-format.md gives the dataset's layout. :mod:`.frame` gives a notebook the same
rows in memory.
"""

from ..validation import MAX_SEED
from .audit import prepare_output
from .frame import evaluate_frame
from .meta import FORMAT, sweep_meta
from .plan import (
                   CALLS_PER_PART,
                   DEFAULT_MEMORY_BUDGET,
                   STEP_COST_US,
                   Chunk,
                   Plan,
                   Variant,
                   describe_plan,
                   plan_sweep,
                   variants,
)
from .read import RowConfig, read_sweep, row_config, sweep_spec
from .run import SweepResult, dry_run, parse_size, run_sweep
from .spec import Setting, SweepSpec, load_spec, parse_spec, read_toml

__all__ = [
    "SweepSpec", "Setting", "load_spec", "parse_spec", "read_toml", "MAX_SEED",
    "Plan", "Chunk", "Variant", "variants", "plan_sweep", "describe_plan", "DEFAULT_MEMORY_BUDGET", "CALLS_PER_PART",
    "STEP_COST_US", "FORMAT", "sweep_meta", "prepare_output", "run_sweep", "dry_run", "SweepResult",
    "parse_size", "read_sweep", "row_config", "sweep_spec", "RowConfig",
    "evaluate_frame",
]

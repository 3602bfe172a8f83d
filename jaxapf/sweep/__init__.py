r"""``jaxapf sweep``: run a study stated in a TOML spec, streaming metrics into a Parquet dataset.

Work and its pieces
-------------------
A spec (:mod:`jaxapf.sweep.spec`) expands into settings; settings with the same static part
(method, convention, simulation and MPC settings) form a **variant**, one compiled program whose
numeric gains are a batched :class:`~jaxapf.gains.Gains` vmapped inside
:func:`jaxapf.engine.evaluate`. A **chunk** is a block of consecutive fields ``[start, stop)`` of one
family × every setting of one variant; it is one call of ``evaluate`` per device and becomes one
Parquet part file ``part-v{variant}-{family}-f{start}-{stop}.parquet`` (docs/sweep-format.md), written
to a hidden temporary name and renamed into place once complete. Only metrics leave the device.

Numbers
-------
Common random numbers: field ``i`` of a family is ``make_scenarios(seed, params, [i])`` for every
setting. The vmap width of ``evaluate`` (``vmap_width``: :func:`~jaxapf.engine.default_width`, or
the smallest power of two >= settings × fields of the largest variant if that is less; a
(variant, family) whose batch working set ``W`` (below) would exceed :data:`WIDTH_BUDGET` runs at
the largest power of two that fits) depends on the spec and the backend only, not on the
chunking, the memory budget or the devices. Every device call holds at
least one whole vmapped batch: a chunk's fields are padded (repeating its first field; the extra
rows are dropped) to ``devices × per_device`` fields with ``per_device · G >= width``, and
``evaluate`` pads the last batch of a device's ``per_device · G`` episodes; every chunk of a
(variant, family) has the same shape (one compile). Every episode is therefore computed by the
same kernels at the same width, and its numbers do not depend on the chunk size, the device
count or which chunks were resumed. A wide width pays on CPU too (XLA spreads one device's wide
kernels over the cores), so the default is one CPU device; with ``--devices N`` a (variant,
family) of fewer than ``N × width`` episodes is padded up to that.

Devices
-------
The fields of a chunk are laid out over the local devices by :class:`jaxapf.engine.devices.DeviceBatch`
(``jax.make_mesh`` + ``NamedSharding``; each device runs the single-device ``evaluate`` program
on its shard, concurrently; why not ``shard_map`` is said there), so the sweep gives the same
numbers on any number of devices. With ``jax.distributed`` each process runs every
``process_count``-th chunk on its own devices and writes only those parts.

Memory
------
Per chunk, the estimate is ``devices × W + G·B_pad × E`` bytes: the working set of one vmapped
batch inside ``evaluate`` per device, ``W = vmap_width·(T+1)·(20 + 3M)·s`` (trajectory, per-step
clearances and metric temporaries), plus per episode ``E = 2[(7M + 12)s + 2M] + 45 s + 320`` (the
gathered scenario and gains, metrics on device and host, the row of the Arrow table), with ``T``
steps, ``M`` obstacle slots, ``s`` bytes per float and ``B_pad`` the padded fields of a chunk.
Without ``--chunk-fields`` the fields of a (variant, family) are cut into the fewest balanced
chunks that fit ``--memory-budget`` and hold at most :data:`CALLS_PER_PART` vmapped batches per
device (so parts finish often: progress, resume). Trajectories never leave ``evaluate``.

Modules: :mod:`.spec` (the TOML spec), :mod:`.plan` (variants, chunks, estimates), :mod:`.schema`
(the Parquet layout), :mod:`.output` (the output directory), :mod:`.run` (the runner),
:mod:`.read` (reading an output back).
"""

from ..validation import MAX_SEED
from .output import prepare_output
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
from .run import SweepResult, configure_jax, default_cache_dir, dry_run, parse_size, run_sweep
from .schema import FORMAT, sweep_meta
from .spec import STATIC_KEYS, RandomRange, Setting, SweepSpec, load_spec, parse_spec, read_toml

__all__ = [
    "SweepSpec", "Setting", "RandomRange", "load_spec", "parse_spec", "read_toml", "STATIC_KEYS", "MAX_SEED",
    "Plan", "Chunk", "Variant", "variants", "plan_sweep", "describe_plan", "DEFAULT_MEMORY_BUDGET", "CALLS_PER_PART",
    "STEP_COST_US", "FORMAT", "sweep_meta", "prepare_output", "run_sweep", "dry_run", "SweepResult",
    "configure_jax", "default_cache_dir", "parse_size", "read_sweep", "row_config", "sweep_spec", "RowConfig",
]

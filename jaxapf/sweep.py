r"""``jaxapf sweep``: run a study stated in a TOML spec, streaming metrics into a Parquet dataset.

Work and its pieces
-------------------
A spec (:mod:`jaxapf.sweep_spec`) expands into settings; settings with the same static part
(method, convention, simulation and MPC settings) form a **variant**, one compiled program whose
numeric gains are a batched :class:`~jaxapf.config.Gains` vmapped inside
:func:`jaxapf.rollout.evaluate`. A **chunk** is a block of consecutive fields ``[start, stop)`` of one
family × every setting of one variant; it is one call of ``evaluate`` per device and becomes one
Parquet part file ``part-v{variant}-{family}-f{start}-{stop}.parquet`` (docs/sweep-format.md), written
to a hidden temporary name and renamed into place once complete. Only metrics leave the device.

Numbers
-------
Common random numbers: field ``i`` of a family is ``make_scenarios(seed, params, [i])`` for every
setting. The vmap width of ``evaluate`` (``vmap_width``: :func:`~jaxapf.rollout.default_chunk`, or
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
The fields of a chunk are laid out over the local devices by :class:`jaxapf.devices.DeviceBatch`
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
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import re
import sys
import time
import warnings
from typing import Any, Callable, Iterable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .config import BoundWarning, ConfigError, Gains, MPCConfig, SimConfig, check_int
from .metrics import METRICS
from .devices import DeviceBatch
from .sweep_spec import GAIN_KEYS, STATIC_KEYS, Setting, SweepSpec

__all__ = [
    "FORMAT",
    "DEFAULT_MEMORY_BUDGET",
    "Chunk",
    "Plan",
    "EpisodeConfig",
    "SweepResult",
    "configure_jax",
    "default_cache_dir",
    "parse_size",
    "plan_sweep",
    "describe_plan",
    "dry_run",
    "run_sweep",
    "read_sweep",
    "episode_config",
]

FORMAT = "jaxapf.sweep/1"
META_KEY = b"jaxapf"
#: Default memory budget of one chunk's working set [bytes].
DEFAULT_MEMORY_BUDGET = 256 * 2**20
#: Largest working set of one vmapped batch (``working_set_bytes``) the vmap width may need: long
#: episodes get a narrower width, so a chunk fits the default ``--memory-budget``.
WIDTH_BUDGET = DEFAULT_MEMORY_BUDGET // 2
#: A part holds at most this many vmapped batches per device (a few seconds to a minute of work
#: on a CPU core at the default MPC settings), so progress and resume have a fine grain.
CALLS_PER_PART = 256
#: Memory of the process besides its chunks (Python, JAX, loaded programs) [bytes]: about 430 MB
#: measured on CPU (jax 0.10, warm cache); XLA compilation adds up to ~1 GB while it runs.
PROCESS_BASELINE = 450 * 2**20
#: Cost model of one episode step [µs of wall time] on one CPU device (float32, vmap width 1024,
#: XLA spreading the kernels over the cores): ``c0 + c_qp·N·I + c_obs·N·M + c_n·N`` (N horizon,
#: I FISTA iterations, M obstacle slots), fitted by ``jaxapf bench --fit-cost`` (least squares on
#: 18 configurations, N 10–40, I 10–60, M 4 and 16) on the 2-core AMD EPYC development machine
#: with the classic loop emitters of ``rollout.XLA_OPTIONS``; the fit is within 0.77–1.46× of
#: every measurement (two fits in a row agreed within 3 % at N = 20, I = 30, M = 16).
STEP_COST_US = (3.002, 0.009114, 0.006484, 0.09848)
#: Cold XLA compile of one evaluate program on that machine [s] (2.5–8 s measured).
COMPILE_S = 4.0
#: The PRNG of the fields and of the random gain samples.
PRNG = {
    "impl": str(jax.config.jax_default_prng_impl),
    "field_key": "fold_in(key(seed), field)",
    "gain_samples": "bits(key(random.seed), (n, gains), uint32); u = (bits + 0.5) / 2**32",
}

_PART = re.compile(r"^part-v(\d{3,})-([a-z_]+)-f(\d{8,})-(\d{8,})\.parquet$")
_TMP = re.compile(r"^\.part-.*\.tmp-\d+$")
_FLAGS = ("success", "collision", "stalled")


# --------------------------------------------------------------------------------------------
# JAX set-up (before any computation)
# --------------------------------------------------------------------------------------------


def default_cache_dir() -> pathlib.Path:
    """``$XDG_CACHE_HOME/jaxapf/xla`` (default ``~/.cache/jaxapf/xla``)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "jaxapf" / "xla"


def configure_jax(*, x64: bool = False, cache_dir: str | os.PathLike | None = None,
                  cpu_devices: int | None = None, distributed: bool = False,
                  cluster: Mapping[str, Any] | None = None) -> None:
    """Process-wide JAX settings for a sweep; call before anything runs on a device.

    Args:
      x64: float64 everywhere (``jax_enable_x64``).
      cache_dir: persistent compilation cache (``jax_compilation_cache_dir``); programs that took
        more than 0.1 s to compile are stored there and loaded by later runs. ``None``: no cache.
      cpu_devices: split the host CPU into this many JAX devices (``jax_num_cpu_devices``), one
        per core being the useful setting; ignored when ``XLA_FLAGS`` already forces a count.
      distributed: ``jax.distributed.initialize(**cluster)`` (multi-process runs). Without
        ``cluster`` JAX detects the cluster (Slurm, Open MPI, TPU pods); elsewhere pass
        ``coordinator_address``, ``num_processes`` and ``process_id``.
    """
    if distributed:
        jax.distributed.initialize(**(cluster or {}))
    if x64:
        jax.config.update("jax_enable_x64", True)
    if cache_dir is not None:
        pathlib.Path(cache_dir).mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(cache_dir))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.1)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    if cpu_devices is not None and "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        try:
            jax.config.update("jax_num_cpu_devices", int(cpu_devices))
        except RuntimeError:  # JAX already ran something in this process: keep its devices
            pass


def parse_size(text: str) -> int:
    """Bytes from ``"512M"``, ``"2G"``, ``"64MiB"``, ``"1e9"`` (K, M, G, T are powers of 1024)."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d*)?(?:e\d+)?)\s*(?:([KMGT])(?:i?B)?|B)?\s*", str(text), re.IGNORECASE)
    if match is None or float(match[1]) < 1:
        raise ConfigError(f"--memory-budget = {text!r} is not a size; write e.g. 256M, 2G or a number of bytes")
    unit = match[2].upper() if match[2] else ""
    return int(float(match[1]) * 1024 ** ("_KMGT".index(unit) if unit else 0))


# --------------------------------------------------------------------------------------------
# planning
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Variant:
    """Settings that share one static configuration (one compiled program per family shape)."""

    index: int
    static: tuple[tuple[str, Any], ...]
    settings: tuple[Setting, ...]

    def gains(self, dtype: Any) -> Gains:
        """The variant's gain settings as a batched :class:`Gains` (leading axis G, ``dtype``)."""
        return _gains({k: np.array([s.gains[k] for s in self.settings], dtype) for k in GAIN_KEYS})


def _gains(values: Mapping[str, Any]) -> Gains:
    """:class:`Gains` of values the spec's validation already checked (and warned about)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BoundWarning)
        return Gains(**values)


def variants(spec: SweepSpec) -> list[Variant]:
    """The spec's settings grouped by static part, in order of first appearance."""
    groups: dict[tuple, list[Setting]] = {}
    for setting in spec.settings():
        groups.setdefault(setting.static, []).append(setting)
    return [Variant(i, static, tuple(group)) for i, (static, group) in enumerate(groups.items())]


@dataclasses.dataclass(frozen=True)
class Chunk:
    """Fields ``[start, stop)`` of ``family`` × every setting of variant ``variant``."""

    variant: int
    family: str
    start: int
    stop: int

    @property
    def name(self) -> str:
        return f"part-v{self.variant:03d}-{self.family}-f{self.start:08d}-{self.stop:08d}.parquet"

    @classmethod
    def from_name(cls, name: str) -> "Chunk | None":
        match = _PART.match(name)
        return None if match is None else cls(int(match[1]), match[2], int(match[3]), int(match[4]))


@dataclasses.dataclass(frozen=True)
class Block:
    """Shapes of the chunks of one (variant, family): ``fields`` per chunk, padded to ``padded =
    devices · per_device`` fields with ``per_device · settings`` at least its vmap ``width``;
    ``bytes``: the memory estimate of one chunk."""

    sim: SimConfig
    mpc: MPCConfig
    obstacles: int
    settings: int
    fields: int
    per_device: int
    padded: int
    bytes: int
    width: int


def _program(block: Block) -> tuple:
    """What identifies a compiled ``evaluate`` program: static configuration and shapes."""
    return block.sim, block.mpc, block.obstacles, block.settings, block.per_device, block.width


def working_set_bytes(width: int, steps: int, obstacles: int, itemsize: int) -> int:
    """``W``: one vmapped batch inside ``evaluate`` (trajectory, clearances, metric temporaries)."""
    return width * (steps + 1) * (20 + 3 * obstacles) * itemsize


def episode_bytes(obstacles: int, itemsize: int) -> int:
    """``E``: memory that grows with the episodes of a chunk, per episode."""
    return 2 * ((7 * obstacles + 12) * itemsize + 2 * obstacles) + 3 * len(METRICS) * itemsize + 320


def step_cost_us(mpc: MPCConfig, obstacles: int) -> float:
    """Cost model of one episode step on one CPU device [µs] (see :data:`STEP_COST_US`)."""
    c0, c_qp, c_obs, c_n = STEP_COST_US
    n = mpc.horizon
    return c0 + c_qp * n * mpc.iters + c_obs * n * obstacles + c_n * n


def _block(sim: SimConfig, mpc: MPCConfig, obstacles: int, settings: int, fields: int, *, devices: int,
           width: int, itemsize: int, budget: int, chunk_fields: int | None) -> Block:
    """Chunk shapes of one (variant, family) at the sweep's vmap ``width``, or at the largest power
    of two whose batch working set fits :data:`WIDTH_BUDGET` if that is less (long episodes).

    Each device gets at least ``ceil(width / G)`` fields, so that its episodes fill at least one
    whole vmapped batch (``evaluate`` pads the last one). Without ``chunk_fields``,
    the fields are split into the fewest chunks that fit the memory budget and the
    :data:`CALLS_PER_PART` cap, balanced, and each chunk is filled up to its padded size.
    """
    fits = WIDTH_BUDGET // working_set_bytes(1, sim.steps, obstacles, itemsize)
    width = min(width, max(1, 1 << (fits.bit_length() - 1)))
    fixed = devices * working_set_bytes(width, sim.steps, obstacles, itemsize)
    per_field = settings * episode_bytes(obstacles, itemsize)
    if chunk_fields is None:
        fit = (budget - fixed) // per_field
        if fit < 1:
            raise ConfigError(f"--memory-budget = {budget} bytes is too small: one field of {settings} settings needs "
                              f"{fixed + per_field} bytes ({sim.steps} steps, {obstacles} obstacle slots)")
        largest = min(fit, math.ceil(CALLS_PER_PART * width * devices / settings))
        block = math.ceil(fields / math.ceil(fields / largest))
    else:
        block = min(chunk_fields, fields)
    per_device = max(math.ceil(block / devices), math.ceil(width / settings))
    padded = per_device * devices
    if chunk_fields is None:
        block = min(padded, fields)
    return Block(sim, mpc, obstacles, settings, block, per_device, padded, fixed + padded * per_field, width)


def _gaps(done: Iterable[tuple[int, int]], fields: int) -> list[tuple[int, int]]:
    """The sub-intervals of ``[0, fields)`` not covered by the ``done`` intervals."""
    gaps, at = [], 0
    for start, stop in sorted(done):
        if start > at:
            gaps.append((at, start))
        at = max(at, stop)
    if at < fields:
        gaps.append((at, fields))
    return gaps


@dataclasses.dataclass(frozen=True)
class Plan:
    """Everything a run needs, decided before it starts.

    Attributes:
      chunks: the chunks still to run, in run order (all processes).
      done: chunks found finished in the output.
      blocks: shapes per (variant index, family).
    """

    spec: SweepSpec
    variants: tuple[Variant, ...]
    blocks: Mapping[tuple[int, str], Block]
    chunks: tuple[Chunk, ...]
    done: tuple[Chunk, ...]
    devices: int
    processes: int
    width: int
    dtype: str

    @property
    def settings(self) -> int:
        return sum(len(v.settings) for v in self.variants)

    @property
    def episodes(self) -> int:
        return self.settings * len(self.spec.families) * self.spec.fields

    def episodes_of(self, chunks: Iterable[Chunk]) -> int:
        return sum(len(self.variants[c.variant].settings) * (c.stop - c.start) for c in chunks)

    @property
    def programs(self) -> int:
        """Distinct compiled ``evaluate`` programs (static configuration × shapes), per device."""
        return len({_program(b) for b in self.blocks.values()})

    @property
    def static_variants(self) -> int:
        """Distinct (SimConfig, MPCConfig) pairs over variants and families."""
        return len({(b.sim, b.mpc) for b in self.blocks.values()})

    def estimate_seconds(self) -> tuple[float, float]:
        """(run, cold compile) seconds from the cost model, for the chunks still to run."""
        run = 0.0
        for c in self.chunks:
            b = self.blocks[(c.variant, c.family)]
            run += b.settings * b.padded * b.sim.steps * step_cost_us(b.mpc, b.obstacles) * 1e-6
        programs = len({_program(self.blocks[(c.variant, c.family)]) for c in self.chunks})
        return run / (self.devices * self.processes), programs * COMPILE_S * self.devices

    @property
    def peak_bytes(self) -> int:
        return max((b.bytes for b in self.blocks.values()), default=0)


def plan_sweep(spec: SweepSpec, *, done: Sequence[Chunk] = (), memory_budget: int = DEFAULT_MEMORY_BUDGET,
               chunk_fields: int | None = None, devices: int | None = None, processes: int = 1,
               width: int | None = None) -> Plan:
    """Cut the spec's work into chunks (skipping the ``done`` ones), see the module docstring."""
    from .rollout import default_chunk

    if chunk_fields is not None:
        chunk_fields = check_int("--chunk-fields", chunk_fields, 1)
    devices = devices or jax.local_device_count()
    dtype = jnp.dtype(jnp.result_type(float))
    groups = variants(spec)
    # the backend's width, or less for a sweep too small to fill it (a power of two; depends on
    # the spec only, so every chunking, device count and memory budget uses the same kernels);
    # each (variant, family) narrows it further if its episodes are long (_block)
    needed = max(len(v.settings) for v in groups) * spec.fields
    width = width or default_chunk(needed)
    blocks, chunks = {}, []
    for v in groups:
        for family in spec.families:
            sim, mpc = spec.configs(v.static, family)
            obstacles = spec.family_params(family).max_obstacles
            block = _block(sim, mpc, obstacles, len(v.settings), spec.fields, devices=devices, width=width,
                           itemsize=dtype.itemsize, budget=memory_budget, chunk_fields=chunk_fields)
            blocks[(v.index, family)] = block
            finished = [(c.start, c.stop) for c in done if (c.variant, c.family) == (v.index, family)]
            for lo, hi in _gaps(finished, spec.fields):
                chunks += [Chunk(v.index, family, a, min(a + block.fields, hi)) for a in range(lo, hi, block.fields)]
    return Plan(spec, tuple(groups), blocks, tuple(chunks), tuple(done), devices, processes, width, str(dtype))


def _fmt_bytes(n: float) -> str:
    power = min(3, int(math.log(max(n, 1), 1024)))
    return f"{n / 1024 ** power:.1f} {('B', 'KiB', 'MiB', 'GiB')[power]}"


def _fmt_seconds(s: float) -> str:
    return (f"{s:.1f} s" if s < 10 else f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min" if s < 7200
            else f"{s / 3600:.1f} h")


def describe_plan(plan: Plan) -> str:
    """What a run of ``plan`` does (``jaxapf sweep --dry-run``)."""
    spec = plan.spec
    run_s, compile_s = plan.estimate_seconds()
    remaining = plan.episodes_of(plan.chunks)
    lines = [
        f"sweep {spec.name} (spec_hash {spec.hash[:12]})",
        f"  settings:          {plan.settings}, in {len(plan.variants)} static variant(s)",
        f"  families:          {len(spec.families)} ({', '.join(spec.families)}), {spec.fields} fields each, "
        f"seed {spec.seed}",
        f"  episodes:          {plan.episodes:,}" + (f" ({plan.episodes - remaining:,} already in the output, "
                                                    f"{remaining:,} to run)" if plan.done else ""),
        f"  compiled variants: {plan.static_variants} distinct (SimConfig, MPCConfig); {plan.programs} evaluate "
        f"program(s) with their shapes, each compiled once per device",
        f"  chunks:            {len(plan.chunks)} to run" + (f", {len(plan.done)} done" if plan.done else "")
        + f" (one Parquet part each), on {plan.devices} device(s) × {plan.processes} process(es), "
          f"vmap width {plan.width}, {plan.dtype}",
    ]
    for v in plan.variants:
        static = ", ".join(f"{k}={json.dumps(x)}" for k, x in v.static) or "defaults"
        for family in spec.families:
            b = plan.blocks[(v.index, family)]
            lines.append(f"    v{v.index:03d} {family:<13s} {static}: {b.settings} settings × {b.fields} fields per "
                         f"chunk (padded {b.padded}), {b.sim.steps} steps, N={b.mpc.horizon}, I={b.mpc.iters}, "
                         f"M={b.obstacles}" + (f", vmap width {b.width}" if b.width != plan.width else ""))
    lines += [
        f"  time estimate:     {_fmt_seconds(run_s)} of simulation + up to {_fmt_seconds(compile_s)} of compilation "
        "(~0 with a warm compilation cache)",
        "                     from a per-step cost model fitted on a 2-core x86-64 CPU (jaxapf.sweep.STEP_COST_US, "
        "±50 %; `jaxapf bench --fit-cost` refits it here); on accelerators it is only an upper bound",
        f"  memory estimate:   {_fmt_bytes(plan.peak_bytes)} per chunk + ~{_fmt_bytes(PROCESS_BASELINE)} for the "
        "process (up to ~1 GiB more while XLA compiles); docs/sweep.md",
    ]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Parquet layout
# --------------------------------------------------------------------------------------------


def _static_columns(spec: SweepSpec) -> tuple[str, ...]:
    """The simulation/MPC settings that get a column: those the spec names (but method and
    convention, which always have one), and ``t_max`` always (its default is the family's)."""
    named = set(spec.static_keys) - {"method", "convention"} | {"t_max"}
    return tuple(k for k in STATIC_KEYS if k in named)


def _spec_values(spec: SweepSpec, key: str) -> list[Any]:
    return [v for k, v in spec.sim.items() if k == key] + [x for k, values in spec.grid if k == key for x in values]


def _column_type(spec: SweepSpec, key: str):
    import pyarrow as pa

    values = _spec_values(spec, key)
    if any(isinstance(v, tuple) for v in values):
        return pa.string()  # per-axis weights given as [x, y, z]: JSON text
    if any(isinstance(v, bool) for v in values):
        return pa.bool_()
    if any(isinstance(v, int) for v in values):
        return pa.int64()
    return pa.float64()


def _schema(spec: SweepSpec, meta: Mapping[str, Any]):
    import pyarrow as pa

    float_type = pa.from_numpy_dtype(np.dtype(meta["dtype"]))
    fields = [pa.field("setting", pa.int32()), pa.field("method", pa.string()), pa.field("convention", pa.string())]
    fields += [pa.field(k, pa.float64()) for k in GAIN_KEYS]
    fields += [pa.field(k, _column_type(spec, k)) for k in _static_columns(spec)]
    fields += [pa.field("family", pa.string()), pa.field("field", pa.int64()), pa.field("seed", pa.int64())]
    fields += [pa.field(m, pa.bool_() if m in _FLAGS else pa.int32() if m == "steps" else float_type)
               for m in METRICS]
    return pa.schema(fields, metadata={META_KEY: json.dumps(meta, sort_keys=True).encode()})


def _cell(value: Any, text: bool) -> Any:
    """A static setting's value in its column (``text``: JSON, for per-axis weights)."""
    return json.dumps(list(value) if isinstance(value, tuple) else value) if text else value


def _part_table(plan: Plan, schema, chunk: Chunk, metrics: Mapping[str, np.ndarray]):
    """The rows of one chunk: settings-major, fields-minor. Every column but the setting index,
    the gains, the field and the metrics is constant within a chunk (one variant, one family)."""
    import pyarrow as pa

    spec, variant = plan.spec, plan.variants[chunk.variant]
    sim = plan.blocks[(chunk.variant, chunk.family)].sim
    n = chunk.stop - chunk.start
    rows = n * len(variant.settings)
    static = dict(variant.static)
    constant = {"method": static.get("method", sim.method), "convention": static.get("convention", sim.convention),
                "family": chunk.family, "seed": spec.seed}
    for k in _static_columns(spec):  # only t_max can be unnamed, and it is a SimConfig field
        constant[k] = _cell(static[k] if k in static else getattr(sim, k), pa.types.is_string(schema.field(k).type))
    cols: dict[str, Any] = {"setting": np.repeat(np.array([s.index for s in variant.settings], np.int32), n),
                            "field": np.tile(np.arange(chunk.start, chunk.stop, dtype=np.int64), len(variant.settings))}
    for k in GAIN_KEYS:
        cols[k] = np.repeat(np.array([s.gains[k] for s in variant.settings], np.float64), n)
    for m in METRICS:
        cols[m] = np.ascontiguousarray(metrics[m][:, :n]).reshape(-1)
    zeros = pa.array(np.zeros(rows, np.int32))
    arrays = [pa.array([constant[f.name]], f.type).take(zeros) if f.name in constant else pa.array(cols[f.name], f.type)
              for f in schema]
    return pa.Table.from_arrays(arrays, schema=schema)


def _write_part(out: pathlib.Path, name: str, table) -> None:
    """Write ``table`` to ``out/name`` atomically: hidden temporary file, fsync, rename."""
    import pyarrow.parquet as pq

    tmp = out / f".{name}.tmp-{os.getpid()}"
    with open(tmp, "wb") as fh:
        pq.write_table(table, fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, out / name)


def _read_meta(path: pathlib.Path) -> dict[str, Any]:
    """The ``jaxapf`` metadata of a part file; :class:`ConfigError` if it has none."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        raw = (pq.read_schema(path).metadata or {}).get(META_KEY)
    except (OSError, pa.ArrowException) as err:
        raise ConfigError(f"{path} is not a readable sweep output (Parquet): {_first_line(err)}") from None
    try:
        meta = json.loads(raw) if raw else None
    except json.JSONDecodeError:
        meta = None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ConfigError(f"{path} is not the output of jaxapf sweep (no '{META_KEY.decode()}' metadata of format "
                          f"{FORMAT} in its Parquet schema)")
    return meta


def _first_line(err: BaseException) -> str:
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


def _parts(out: pathlib.Path) -> list[pathlib.Path]:
    return sorted(p for p in out.iterdir() if Chunk.from_name(p.name) is not None)


# --------------------------------------------------------------------------------------------
# the output directory
# --------------------------------------------------------------------------------------------


def _identity(meta: Mapping[str, Any]) -> dict[str, Any]:
    """What must match for parts to belong to one sweep (numbers bit for bit)."""
    return {k: meta.get(k) for k in ("spec_hash", "dtype", "vmap_width")}


def prepare_output(out: pathlib.Path, meta: Mapping[str, Any], *, overwrite: bool, clean: bool) -> list[Chunk]:
    """Check ``out`` against this sweep and return the chunks already finished there.

    Refuses (:class:`ConfigError`) a path that is a file, a directory holding other files, or parts
    of a different sweep (spec hash, dtype or vmap width) unless ``overwrite``, which deletes the
    parts (and nothing else). With ``clean`` (one process only), stale temporary files of a killed
    run are removed.
    """
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} is a file; a sweep writes a directory of Parquet parts")
    if not out.exists():
        return []
    foreign = [p.name for p in out.iterdir()
               if Chunk.from_name(p.name) is None and not _TMP.match(p.name)]
    if foreign:
        raise ConfigError(f"--out {out} holds files that are not sweep parts ({', '.join(sorted(foreign)[:3])}); "
                          "choose another --out")
    parts = _parts(out)
    if parts and not overwrite:
        old = _identity(_read_meta(parts[0]))
        new = _identity(meta)
        if old != new:
            what = "; ".join(f"{k} {old[k]!s:.12} here, {new[k]!s:.12} now" for k in new if old[k] != new[k])
            raise ConfigError(f"--out {out} holds a different sweep ({what}); rerun with --overwrite to replace it, "
                              "or choose another --out")
    if clean:
        for p in out.iterdir():
            if _TMP.match(p.name) or (overwrite and p in parts):
                p.unlink()
    return [] if overwrite else [Chunk.from_name(p.name) for p in parts]


# --------------------------------------------------------------------------------------------
# running
# --------------------------------------------------------------------------------------------


class _Devices:
    """Runs the chunks of a plan on the local devices (:class:`~jaxapf.devices.DeviceBatch`)."""

    def __init__(self, plan: Plan):
        self.batch = DeviceBatch(jax.local_devices()[: plan.devices])
        self.plan = plan
        self._gains: dict[int, list[Gains]] = {}

    def close(self) -> None:
        self.batch.close()

    def _variant_gains(self, variant: Variant) -> list[Gains]:
        if variant.index not in self._gains:
            self._gains[variant.index] = self.batch.put_gains(variant.gains(self.plan.dtype))
        return self._gains[variant.index]

    def dispatch(self, chunk: Chunk) -> dict[str, jax.Array]:
        """Start the chunk (asynchronously); returns global (G, padded) metric arrays."""
        from .scenarios import make_scenarios

        plan = self.plan
        block = plan.blocks[(chunk.variant, chunk.family)]
        indices = np.full(block.padded, chunk.start, np.int64)
        indices[: chunk.stop - chunk.start] = np.arange(chunk.start, chunk.stop)
        fields = make_scenarios(plan.spec.seed, plan.spec.family_params(chunk.family), jnp.asarray(indices))
        return self.batch.evaluate(fields, self._variant_gains(plan.variants[chunk.variant]), block.sim, block.mpc,
                                   block.width)


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """What a run did: episodes run now and found done, parts written, wall time."""

    out: pathlib.Path
    episodes: int
    skipped: int
    parts: int
    seconds: float

    def summary(self, name: str) -> str:
        rate = self.episodes / self.seconds if self.seconds > 0 else 0.0
        skipped = f" ({self.skipped:,} already done)" if self.skipped else ""
        return (f"sweep {name}: {self.episodes:,} episodes{skipped} in {self.seconds:.1f} s, "
                f"{rate:,.1f} episodes/s -> {self.out}")


def sweep_meta(spec: SweepSpec, plan: Plan) -> dict[str, Any]:
    """The ``jaxapf`` metadata of every part (docs/sweep-format.md)."""
    from .versions import versions

    return {"format": FORMAT, "spec": spec.to_json(), "spec_hash": spec.hash, "versions": versions(),
            "prng": PRNG, "dtype": plan.dtype, "vmap_width": plan.width}


def _sync(name: str) -> None:
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


def dry_run(spec: SweepSpec, out: str | os.PathLike, *, overwrite: bool = False, **plan: Any) -> str:
    """:func:`describe_plan` of what :func:`run_sweep` would do with ``out`` as it is now
    (refusing, like the run, an output of a different sweep); ``plan``: :func:`plan_sweep` options."""
    done = prepare_output(pathlib.Path(out), sweep_meta(spec, plan_sweep(spec, **plan)), overwrite=overwrite,
                          clean=False)
    return describe_plan(plan_sweep(spec, done=done, **plan))


def run_sweep(
    spec: SweepSpec,
    out: str | os.PathLike,
    *,
    memory_budget: int = DEFAULT_MEMORY_BUDGET,
    chunk_fields: int | None = None,
    overwrite: bool = False,
    quiet: bool = False,
    devices: int | None = None,
    after_part: Callable[[Chunk], None] | None = None,
) -> SweepResult:
    """Run (or resume) ``spec`` into the Parquet dataset directory ``out``.

    Finished parts already in ``out`` are kept and their chunks skipped; the fields they do not
    cover are cut into chunks of the current size. ``after_part`` is called after each part is
    written (tests use it to interrupt a run). In a multi-process run (``jax.distributed``), process
    ``p`` runs chunks ``p, p + P, p + 2P, …`` of the plan.
    """
    start = time.perf_counter()
    out = pathlib.Path(out)
    process, processes = jax.process_index(), jax.process_count()
    probe = plan_sweep(spec, memory_budget=memory_budget, chunk_fields=chunk_fields, devices=devices,
                       processes=processes)
    meta = sweep_meta(spec, probe)
    prepare_output(out, meta, overwrite=overwrite, clean=process == 0)
    _sync("jaxapf-sweep-prepared")
    done = prepare_output(out, meta, overwrite=False, clean=False)
    _sync("jaxapf-sweep-listed")
    plan = plan_sweep(spec, done=done, memory_budget=memory_budget, chunk_fields=chunk_fields, devices=devices,
                      processes=processes)
    mine = plan.chunks[process::processes]
    out.mkdir(parents=True, exist_ok=True)
    schema = _schema(spec, meta)
    total = plan.episodes_of(mine)
    from tqdm import tqdm

    bar = tqdm(total=total, unit="ep", unit_scale=True, desc=spec.name, dynamic_ncols=True,
               disable=quiet or not sys.stderr.isatty())
    runner = _Devices(plan)
    written = 0
    try:
        pending: tuple[Chunk, dict[str, jax.Array]] | None = None
        for chunk in (*mine, None):
            running = None if chunk is None else (chunk, runner.dispatch(chunk))
            if pending is not None:  # write the previous chunk while this one runs
                done_chunk, arrays = pending
                metrics = {m: np.asarray(a) for m, a in arrays.items()}
                _write_part(out, done_chunk.name, _part_table(plan, schema, done_chunk, metrics))
                written += 1
                bar.update(plan.episodes_of([done_chunk]))
                if after_part is not None:
                    after_part(done_chunk)
            pending = running
    finally:
        runner.close()
        bar.close()
    return SweepResult(out, total, plan.episodes_of(done), written, time.perf_counter() - start)


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------


def read_sweep(path: str | os.PathLike) -> tuple["pd.DataFrame", dict[str, Any]]:  # noqa: F821
    """The rows of a sweep output (sorted by setting, family in spec order, field) and its metadata.

    ``path`` is the output directory (every visible ``*.parquet`` in it is a part) or one part file.
    The metadata is the parts' ``jaxapf`` object (docs/sweep-format.md) plus ``parts`` (number of
    part files), ``rows_expected`` (from the spec; None if the spec cannot be expanded) and
    ``complete`` (every (setting, family, field) present). Raises :class:`ConfigError` for a path
    that is not a sweep output, or whose parts belong to different sweeps.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = pathlib.Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: no such file or directory")
    parts = sorted(p for p in path.glob("*.parquet") if p.is_file() and not p.name.startswith((".", "_"))) \
        if path.is_dir() else [path]
    if not parts:
        raise ConfigError(f"{path} is not the output of jaxapf sweep: the directory holds no Parquet part file")
    metas = [_read_meta(p) for p in parts]
    if len({json.dumps(_identity(m), sort_keys=True) for m in metas}) > 1:
        raise ConfigError(f"{path} mixes parts of different sweeps (their spec_hash, dtype or vmap_width differ)")
    try:
        df = pa.concat_tables([pq.read_table(p) for p in parts]).to_pandas()
    except (OSError, pa.ArrowException) as err:
        raise ConfigError(f"{path} is not a readable sweep output (Parquet): {_first_line(err)}") from None
    meta = metas[0]
    if {"setting", "family", "field"} <= set(df.columns):
        families = list(meta.get("spec", {}).get("scenario", {}).get("families", []))
        rank = {f: i for i, f in enumerate(families + sorted(set(df["family"]) - set(families)))}
        df = (df.assign(_rank=df["family"].map(rank)).sort_values(["setting", "_rank", "field"], kind="stable")
              .drop(columns="_rank").reset_index(drop=True))
    try:
        spec = SweepSpec.from_json(meta["spec"])
        expected = len(spec.settings()) * len(spec.families) * spec.fields
    except (KeyError, TypeError, ConfigError):
        expected = None
    return df, {**meta, "parts": len(parts), "rows_expected": expected, "complete": len(df) == expected}


@dataclasses.dataclass(frozen=True)
class EpisodeConfig:
    """Everything needed to re-simulate one row with :func:`jaxapf.simulate.simulate_runs`:
    ``simulate_runs(c.family, c.seed, c.field, [c.sim.method], c.gains, c.sim, c.mpc, c.overrides)``
    (in float64 if ``c.dtype`` is float64: enable ``jax_enable_x64`` first)."""

    family: str
    params: Any
    overrides: Mapping[str, Any]
    seed: int
    field: int
    gains: Gains
    sim: SimConfig
    mpc: MPCConfig
    dtype: str


def episode_config(meta: Mapping[str, Any], row: Mapping[str, Any]) -> EpisodeConfig:
    """The configuration of one output row (``meta`` from :func:`read_sweep`)."""
    spec = SweepSpec.from_json(meta["spec"])
    setting = spec.settings()[int(row["setting"])]
    family = str(row["family"])
    sim, mpc = spec.configs(setting.static, family)
    return EpisodeConfig(family=family, params=spec.family_params(family), overrides=dict(spec.params.get(family, {})),
                         seed=spec.seed, field=int(row["field"]), gains=_gains(setting.gains), sim=sim, mpc=mpc,
                         dtype=str(meta["dtype"]))

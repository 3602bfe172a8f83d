"""Planning a sweep: variants, chunks and their shapes, and the time and memory estimates.

docs/sweep.md says what the pieces are and why every episode runs at the same vmap width.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from typing import Any, Iterable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..config import MPCConfig, SimConfig
from ..engine.policy import CPU, Policy, free_memory, policy_for
from ..gains import GAINS, Gains
from ..metrics import METRICS
from ..metrics.swarm import swarm_metric_names
from ..text import format_bytes, format_seconds
from ..validation import ConfigError, check_int
from .meta import sweep_meta
from .spec import Setting, SweepSpec

__all__ = [
    "DEFAULT_MEMORY_BUDGET",
    "WIDTH_BUDGET",
    "CALLS_PER_PART",
    "PROCESS_BASELINE",
    "STEP_COST_US",
    "COMPILE_S",
    "Variant",
    "variants",
    "Chunk",
    "Block",
    "Plan",
    "plan_sweep",
    "describe_plan",
    "working_set_bytes",
    "episode_bytes",
    "step_cost_us",
    "seen_slots",
    "gaps",
    "parse_shard",
    "shard_chunks",
    "chunk_cost",
]

#: Default memory budget of one chunk's working set on CPU [bytes] (an accelerator's: half its free
#: memory, :class:`~jaxapf.engine.policy.Policy`).
DEFAULT_MEMORY_BUDGET = CPU.budget
#: Largest working set of one vmapped batch (``working_set_bytes``) the vmap width may need on CPU: long
#: episodes get a narrower width, so a chunk fits the default ``--memory-budget``.
WIDTH_BUDGET = CPU.width_budget
#: A part holds at most this many vmapped batches per device (a few seconds to a minute of work
#: on a CPU core at the default MPC settings), so progress and resume have a fine grain.
CALLS_PER_PART = 256
#: Memory of the process besides its chunks (Python, JAX, loaded programs) [bytes], on CPU with a
#: warm cache; XLA compilation adds more while it runs.
PROCESS_BASELINE = 450 * 2**20
#: Cost model of one episode step [µs of wall time] on one CPU device (float32, vmap width 1024,
#: XLA spreading the kernels over the cores): ``c0 + c_qp·N·I + c_obs·N·M + c_n·N`` (N horizon,
#: I FISTA iterations, M obstacle slots), fitted by ``benchmarks/fit_cost.py`` (least squares on
#: 18 configurations, N 10–40, I 10–60, M 4 and 16) on the 2-core development machine with
#: :data:`jaxapf.engine.XLA_OPTIONS`; docs/performance.md gives how far the fit is from its
#: measurements.
STEP_COST_US = (3.002, 0.009114, 0.006484, 0.09848)
#: Cold XLA compile of one (streaming) evaluate program on that machine [s]: an upper estimate,
#: for families with many obstacle slots.
COMPILE_S = 6.0

_PART = re.compile(r"^part-v(\d{3,})-([A-Za-z_][A-Za-z0-9_]*)-f(\d{8,})-(\d{8,})\.parquet$")


@dataclasses.dataclass(frozen=True)
class Variant:
    """Settings that share one static configuration (one compiled program per family shape).

    ``inverse[i]`` is the position of setting ``i``'s episodes among the ``simulated`` settings:
    settings that agree on every gain the variant's planner, filter and plant read
    (:func:`~jaxapf.engine.gains_read`) -- e.g. ``basic`` at two values of γ, which it ignores --
    fly the same episodes, so only the first of them is simulated and its rows are repeated.
    """

    index: int
    static: tuple[tuple[str, Any], ...]
    settings: tuple[Setting, ...]
    simulated: tuple[int, ...]
    inverse: tuple[int, ...]

    @property
    def duplicates(self) -> int:
        """Settings that repeat an earlier one of the variant in every gain it reads."""
        return len(self.settings) - len(self.simulated)

    def gains(self, dtype: Any) -> Gains:
        """The simulated settings' gains as a batched :class:`Gains` (leading axis, ``dtype``)."""
        chosen = [self.settings[i] for i in self.simulated]
        return Gains.unchecked({k: np.array([s.gains[k] for s in chosen], dtype) for k in GAINS.names()})


def variants(spec: SweepSpec) -> list[Variant]:
    """The spec's settings grouped by static part, in order of first appearance, each group with
    its distinct settings (:class:`Variant`)."""
    from ..engine import gains_read

    groups: dict[tuple, list[Setting]] = {}
    for setting in spec.settings():
        groups.setdefault(setting.static, []).append(setting)
    out = []
    for i, (static, group) in enumerate(groups.items()):
        read = sorted(gains_read(spec.configs(static, spec.families[0])[0]))
        first: dict[tuple, int] = {}
        simulated, inverse = [], []
        for j, setting in enumerate(group):
            key = tuple(setting.gains[k] for k in read)
            if key not in first:
                first[key] = len(simulated)
                simulated.append(j)
            inverse.append(first[key])
        out.append(Variant(i, static, tuple(group), tuple(simulated), tuple(inverse)))
    return out


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
        match = _PART.fullmatch(name)
        return None if match is None else cls(int(match[1]), match[2], int(match[3]), int(match[4]))


@dataclasses.dataclass(frozen=True)
class Block:
    """Shapes of the chunks of one (variant, family): ``fields`` per chunk, padded to ``padded =
    devices · per_device`` fields with ``per_device · settings`` at least its vmap ``width``;
    ``bytes``: the memory estimate of one chunk; ``agents``: UAVs per field (1 but in a swarm family);
    ``fused``: the fused program its method flies in (:func:`fuse`; empty: its own), as method ``choice``."""

    sim: SimConfig
    mpc: MPCConfig
    obstacles: int
    settings: int
    agents: int
    fields: int
    per_device: int
    padded: int
    bytes: int
    width: int
    fused: str = ""
    choice: int = 0

    @property
    def flown(self) -> SimConfig:
        """The configuration the engine compiles: :attr:`sim`, or with the fused program's method."""
        return self.sim.replace(method=self.fused) if self.fused else self.sim


def _program(block: Block) -> tuple:
    """What identifies a compiled ``evaluate`` program: static configuration and shapes."""
    return block.flown, block.mpc, block.obstacles, block.agents, block.settings, block.per_device, block.width


def fuse(spec: SweepSpec, groups: Sequence[Variant]) -> dict[int, tuple[str, int]]:
    """The fused program (its method, :func:`~jaxapf.planners.apf.fused`) and method choice of each variant whose
    static settings differ from another's only in a potential-field method (:func:`~jaxapf.planners.apf.fusable`):
    such variants fly one compiled program, each episode with its own weight (the accelerator policy)."""
    from ..planners import PLANNERS
    from ..planners.apf import FUSED, fusable

    alike: dict[tuple, dict[str, list[int]]] = {}
    for v in groups:
        method = spec.configs(v.static, spec.families[0])[0].planner.method
        if fusable(PLANNERS.get(method, "method")):
            rest = tuple((k, x) for k, x in v.static if k != "method")
            alike.setdefault(rest, {}).setdefault(method, []).append(v.index)
    out = {}
    for methods in alike.values():
        if len(methods) > 1:
            name = FUSED.join(methods)
            out |= {i: (name, choice) for choice, indices in enumerate(methods.values()) for i in indices}
    return out


def working_set_bytes(width: int, steps: int, obstacles: int, itemsize: int, agents: int = 1) -> int:
    """``W``: ``width`` episodes inside ``evaluate``: the streaming engine's record ring and store of
    finished episodes (about 2.3 trajectories of 9 numbers per sample each) and the metrics'
    temporaries (clearances to every obstacle slot). A swarm episode of ``agents`` UAVs counts as that
    many episodes, each among ``obstacles`` slots (:func:`seen_slots`: the other UAVs are obstacles to it)."""
    return width * agents * (steps + 1) * (41 + 3 * obstacles) * itemsize


def seen_slots(sim: SimConfig, obstacles: int, agents: int) -> int:
    """The obstacle slots each UAV's stack works on: the field's ``obstacles``, and in a swarm of ``agents``
    the neighbour slots (:func:`~jaxapf.datatypes.swarm.neighbour_slots`; with every other UAV, one of them
    its own, left invalid)."""
    from ..datatypes.swarm import neighbour_slots

    return obstacles + neighbour_slots(agents, sim.world.max_neighbours)


def episode_bytes(obstacles: int, itemsize: int, agents: int = 1) -> int:
    """``E``: memory that grows with the episodes of a chunk, per episode (a swarm's: its fields hold
    ``agents`` starts and goals, its rows the swarm metrics)."""
    metrics = len(METRICS) if agents == 1 else len(swarm_metric_names())
    return 2 * ((7 * obstacles + 6 + 6 * agents) * itemsize + 2 * obstacles + agents - 1) + 3 * metrics * itemsize + 320


def step_cost_us(mpc: MPCConfig, obstacles: int, agents: int = 1) -> float:
    """Cost model of one episode step on one CPU device [µs] (see :data:`STEP_COST_US`); a swarm's step is
    ``agents`` UAVs' steps, each among ``obstacles`` slots (:func:`seen_slots`)."""
    c0, c_qp, c_obs, c_n = STEP_COST_US
    n = mpc.horizon
    return agents * (c0 + c_qp * n * mpc.iters + c_obs * n * obstacles + c_n * n)


def _block(sim: SimConfig, mpc: MPCConfig, obstacles: int, agents: int, settings: int, fields: int, *, devices: int,
           width: int, itemsize: int, budget: int, chunk_fields: int | None, family: str = "",
           width_budget: int = WIDTH_BUDGET) -> Block:
    """Chunk shapes of one (variant, family) at the sweep's vmap ``width``, or at the largest power
    of two whose batch working set fits ``width_budget`` if that is less (long episodes).

    Each device gets at least ``ceil(width / G)`` fields, so that its episodes fill at least one
    whole vmapped batch (``evaluate`` pads the last one). Without ``chunk_fields``,
    the fields are split into the fewest chunks that fit the memory budget and the
    :data:`CALLS_PER_PART` cap, balanced, and each chunk is filled up to its padded size.
    """
    seen = seen_slots(sim, obstacles, agents)
    steps = sim.episode.steps
    per_field = settings * episode_bytes(obstacles, itemsize, agents)
    one = working_set_bytes(1, steps, seen, itemsize, agents)
    if devices * one + per_field > budget:  # not even one episode at a time fits: a limit of the spec
        per_step = working_set_bytes(1, 0, seen, itemsize, agents)  # one sample of one episode
        most_steps = max((budget - per_field) // devices // per_step - 1, 0)
        most_slots = max(((budget - per_field) // devices // ((steps + 1) * itemsize * agents) - 41) // 3
                         - (seen - obstacles), 0)
        raise ConfigError(
            f"{family}: one episode of {steps:,} steps (t_max {sim.episode.t_max:g} s at dt {sim.episode.dt:g} s) "
            f"among {obstacles:,} obstacle slots needs {format_bytes(devices * one + per_field)} of working memory, "
            f"more than --memory-budget {format_bytes(budget)}: at most {most_steps:,} steps (t_max <= "
            f"{most_steps * sim.episode.dt:g} s) with these slots, or at most {most_slots:,} obstacle slots at this "
            "length; or a larger --memory-budget")
    fits = width_budget // one
    width = min(width, 1 << max(fits.bit_length() - 1, 0))
    fixed = devices * working_set_bytes(width, steps, seen, itemsize, agents)
    if chunk_fields is None:
        least = devices * math.ceil(width / settings)  # the fewest fields a chunk is padded to
        if fixed + least * per_field > budget:
            raise ConfigError(f"--memory-budget = {format_bytes(budget)} is too small: a chunk here needs at least "
                              f"{format_bytes(fixed + least * per_field)} (one vmapped batch of {width} episodes on "
                              f"each of {devices} device(s): {least} fields × {settings} settings, {steps} steps, "
                              f"{obstacles} obstacle slots)")
        fit = (budget - fixed) // per_field
        largest = min(fit, math.ceil(CALLS_PER_PART * width * devices / settings))
        block = math.ceil(fields / math.ceil(fields / largest))
    else:
        block = min(chunk_fields, fields)
    per_device = max(math.ceil(block / devices), math.ceil(width / settings))
    padded = per_device * devices
    if chunk_fields is None:
        block = min(padded, fields)
    return Block(sim, mpc, obstacles, settings, agents, block, per_device, padded, fixed + padded * per_field, width)


def gaps(done: Iterable[tuple[int, int]], fields: int) -> list[tuple[int, int]]:
    """The sub-intervals of ``[0, fields)`` not covered by the ``done`` intervals (those reaching past
    ``fields`` cover no more than ``fields``)."""
    out, at = [], 0
    for start, stop in sorted(done):
        if start > at:
            out.append((at, min(start, fields)))
        at = max(at, stop)
    if at < fields:
        out.append((at, fields))
    return [(a, b) for a, b in out if a < b]


@dataclasses.dataclass(frozen=True)
class Plan:
    """Everything a run needs, decided before it starts.

    Attributes:
      chunks: the chunks still to run, in run order.
      done: chunks found finished in the output.
      blocks: shapes per (variant index, family).
      width: the sweep's vmap width.
      metrics: the metrics every episode yields (the registry's at planning time).
      gain_columns: the gains that get a column (:meth:`SweepSpec.gain_columns`).
      meta: the metadata every part carries, the sweep's identity (:func:`~jaxapf.sweep.meta.sweep_meta`);
        the audit judges an output's parts against it.
      chunk_fields, memory_budget: what cut the chunks (``--chunk-fields``, ``--memory-budget``).
      policy: how the chunks fill the backend (:class:`~jaxapf.engine.policy.Policy`).
      obstacle_slots: the slot count every family is padded to (the policy's ``common_slots``), or None.
      answers: the folder of the oracle's kept answers (:mod:`jaxapf.scenarios.answers`), or None (asked anew).
    """

    spec: SweepSpec
    variants: tuple[Variant, ...]
    blocks: Mapping[tuple[int, str], Block]
    chunks: tuple[Chunk, ...]
    done: tuple[Chunk, ...]
    devices: int
    width: int
    dtype: str
    metrics: tuple[str, ...]
    gain_columns: tuple[str, ...]
    meta: Mapping[str, Any]
    chunk_fields: int | None = None
    memory_budget: int = DEFAULT_MEMORY_BUDGET
    policy: Policy = CPU
    obstacle_slots: int | None = None
    answers: str | None = None

    def resumed(self, done: Sequence[Chunk]) -> "Plan":
        """This plan with ``done`` finished and :meth:`chunks_left` to run (the blocks, the costly part of
        planning, are kept)."""
        return dataclasses.replace(self, chunks=self.chunks_left(done), done=tuple(done))

    def chunks_left(self, done: Sequence[Chunk]) -> tuple[Chunk, ...]:
        """The chunks that fill the gaps ``done`` leaves, each block cut at its own size."""
        chunks = []
        for v in self.variants:
            for family in self.spec.families:
                block = self.blocks[(v.index, family)]
                finished = [(c.start, c.stop) for c in done if (c.variant, c.family) == (v.index, family)]
                for lo, hi in gaps(finished, self.spec.fields):
                    chunks += [Chunk(v.index, family, a, min(a + block.fields, hi))
                               for a in range(lo, hi, block.fields)]
        return tuple(chunks)

    @property
    def settings(self) -> int:
        return sum(len(v.settings) for v in self.variants)

    @property
    def episodes(self) -> int:
        return self.settings * len(self.spec.families) * self.spec.fields

    @property
    def duplicates(self) -> int:
        """Settings run once for an identical earlier one (:class:`Variant`)."""
        return sum(v.duplicates for v in self.variants)

    def episodes_of(self, chunks: Iterable[Chunk]) -> int:
        return sum(len(self.variants[c.variant].settings) * (c.stop - c.start) for c in chunks)

    @property
    def programs(self) -> int:
        """Distinct compiled ``evaluate`` programs (static configuration × shapes), per device."""
        return len({_program(b) for b in self.blocks.values()})

    @property
    def static_variants(self) -> int:
        """Distinct (SimConfig, MPCConfig) pairs over variants and families."""
        return len({(b.flown, b.mpc) for b in self.blocks.values()})

    def estimate_seconds(self) -> tuple[float, float]:
        """(run, cold compile) seconds from the cost model, for the chunks still to run; the run is an
        upper bound: every episode flying its whole ``t_max``."""
        run = 0.0
        for c in self.chunks:
            b = self.blocks[(c.variant, c.family)]
            seen = seen_slots(b.sim, b.obstacles, b.agents)
            run += b.settings * b.padded * b.sim.episode.steps * step_cost_us(b.mpc, seen, b.agents) * 1e-6
        programs = len({_program(self.blocks[(c.variant, c.family)]) for c in self.chunks})
        return run / self.devices, programs * COMPILE_S * self.devices

    def gains(self, variant: Variant) -> Gains:
        """The gains the engine flies ``variant``'s simulated settings with: :meth:`Variant.gains`, and in a fused
        program the method's choice (``weight_choice``, :class:`~jaxapf.planners.weights.Chosen`)."""
        gains = variant.gains(self.dtype)
        block = self.blocks[(variant.index, self.spec.families[0])]
        if not block.fused:
            return gains
        from ..planners.weights import CHOICE

        return Gains.unchecked({**gains, CHOICE.name: np.full(len(variant.simulated), block.choice, self.dtype)})

    @property
    def fused(self) -> tuple[str, ...]:
        """The fused programs' methods (:func:`fuse`), as the parts record them."""
        return tuple(self.meta.get("fused", ()))

    def flown(self, fields: Any) -> Any:
        """A chunk's ``fields`` as the engine flies them: padded to :attr:`obstacle_slots` where the policy
        shares one program among families."""
        if self.obstacle_slots is None:
            return fields
        return dataclasses.replace(fields, obstacles=fields.obstacles.padded(self.obstacle_slots))

    def control_steps(self) -> int:
        """Sequential control steps of the chunks still to run on one device, at most (every episode
        flying its whole ``t_max``): per chunk, the episodes a device flies queued on the streaming
        engine's slots (:func:`~jaxapf.engine.stream.stream_slots`), one after the other on each slot."""
        from ..engine.stream import SEGMENT, stream_slots

        total = 0
        for c in self.chunks:
            b = self.blocks[(c.variant, c.family)]
            episodes = b.settings * b.per_device
            rounds = -(-episodes // stream_slots(episodes, b.width, self.policy.refill))
            total += rounds * SEGMENT * -(-b.sim.episode.steps // SEGMENT)
        return total

    def padding_note(self, chunks: Sequence[Chunk] | None = None) -> str | None:
        """One line when more than 10 % of the episodes still to simulate (``chunks``, default the plan's)
        are padding (chunks filled up to whole vmapped batches on every device, e.g. after an odd
        ``--chunk-fields``)."""
        real = padded = 0
        worst = None
        for c in self.chunks if chunks is None else chunks:
            b = self.blocks[(c.variant, c.family)]
            real += b.settings * (c.stop - c.start)
            padded += b.settings * b.padded
            if worst is None or b.padded - b.fields > worst.padded - worst.fields:
                worst = b
        if padded == 0 or (padded - real) / padded <= 0.1:
            return None
        share = f"{100 * (padded - real) / padded:.0f} % of the episodes to simulate are padding"
        if worst.padded > self.spec.fields:  # the spec's fields do not fill one batch: no chunk size helps
            settings = f"{worst.settings} setting{'s' if worst.settings > 1 else ''}"
            return (f"{share}: the spec's {self.spec.fields} fields × {settings} fill less than one vmapped batch "
                    f"of {worst.width} episodes (padded to {worst.padded} fields), so up to {worst.padded} fields "
                    "per family would take about the same time")
        return (f"{share}: chunks of {worst.fields} fields are padded to {worst.padded} to fill whole vmapped "
                f"batches; --chunk-fields {worst.padded} (or a multiple) avoids it")

    @property
    def peak_bytes(self) -> int:
        return max((b.bytes for b in self.blocks.values()), default=0)


#: Most chunks (each one Parquet part and one Python object) a plan may hold.
MAX_CHUNKS = 1_000_000


def plan_sweep(spec: SweepSpec, *, done: Sequence[Chunk] = (), memory_budget: int | None = None,
               chunk_fields: int | None = None, devices: int | None = None, width: int | None = None,
               backend: str | None = None, out: str | os.PathLike[str] | None = None,
               versions: Mapping[str, str] | None = None, metrics: Sequence[str] | None = None,
               policy: str | None = None, free: int | None = None) -> Plan:
    """Cut the spec's work into chunks (skipping the ``done`` ones), as docs/sweep.md says; ``backend``
    and ``versions``: the JAX backend and package versions of the process the chunks will run in
    (default this one's; a Ray run's are its workers'); ``out``: the output folder (where the parts
    record their ``.py`` plugins from); ``metrics``: default the registry's; ``policy``: ``--policy``
    (default the backend's, :func:`~jaxapf.engine.policy.policy_for`); ``memory_budget``: default the
    policy's, from ``free`` device memory (default this process's first device's)."""
    from ..engine import default_width

    chosen = policy_for(backend, policy)
    if memory_budget is None:
        if chosen.budget is None and free is None and backend is None:  # this process's device says what it has
            free = free_memory()
        memory_budget = chosen.memory_budget(free)
    if chunk_fields is not None:
        chunk_fields = check_int("--chunk-fields", chunk_fields, 1)
    devices = devices or jax.local_device_count()
    dtype = jnp.dtype(jnp.result_type(float))
    groups = variants(spec)
    # the backend's width, or less for a sweep too small to fill it (a power of two; depends on
    # the spec only, so every chunking, device count and memory budget uses the same kernels);
    # each (variant, family) narrows it further if its episodes are long (_block)
    needed = max(len(v.simulated) for v in groups) * spec.fields
    width = width or default_width(needed, widest=chosen.width)
    # the accelerator's families share one program per variant: every field padded to the largest slot count
    # (a swarm's neighbour slots follow its agents, so swarm families keep their own)
    counts = {spec.family_params(f).max_obstacles for f in spec.families}
    slots = max(counts) if chosen.common_slots and not spec.swarm and len(counts) > 1 else None  # None: no padding
    fused = fuse(spec, groups) if chosen.fuse else {}
    blocks = {}
    for v in groups:
        for family in spec.families:
            sim, mpc = spec.configs(v.static, family)
            params = spec.family_params(family)
            agents = params.agents if spec.swarm else 1
            block = _block(sim, mpc, slots or params.max_obstacles, agents, len(v.simulated), spec.fields,
                           devices=devices, width=width, itemsize=dtype.itemsize, budget=memory_budget,
                           chunk_fields=chunk_fields, family=family, width_budget=chosen.batch_budget(memory_budget))
            blocks[(v.index, family)] = dataclasses.replace(block, fused=fused[v.index][0], choice=fused[v.index][1]) \
                if v.index in fused else block
    count = sum(-(-spec.fields // b.fields) for b in blocks.values())
    if count > MAX_CHUNKS:
        raise ConfigError(f"the sweep would be cut into {count:,} chunks (parts); at most {MAX_CHUNKS:,} are allowed: "
                          "fewer scenario.fields, or larger chunks (--chunk-fields, --memory-budget)")
    metrics = tuple(metrics or (swarm_metric_names() if spec.swarm else METRICS.names()))
    meta = sweep_meta(spec, str(dtype), width, metrics, out, versions, slots,
                      sorted({name for name, _ in fused.values()}))
    return Plan(spec, tuple(groups), blocks, (), (), devices, width, str(dtype), metrics, spec.gain_columns(), meta,
                chunk_fields, memory_budget, chosen, slots).resumed(done)


#: Most shards of one sweep (``--shard I/N``): far past any scheduler's job array.
MAX_SHARDS = 1_000_000


def parse_shard(text: str) -> tuple[int, int]:
    """``(i, n)`` from ``"I/N"`` (``--shard``; ``0 <= I < N``), or :class:`ConfigError` in one line."""
    match = re.fullmatch(r"\s*(\d{1,12})\s*/\s*(\d{1,12})\s*", str(text))
    if match is None or int(match[2]) < 1 or int(match[1]) >= int(match[2]) or int(match[2]) > MAX_SHARDS:
        raise ConfigError(f"--shard = {text!r} must be I/N with 0 <= I < N <= {MAX_SHARDS:,}, e.g. 3/64 (a Slurm "
                          "array task: --shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)")
    return int(match[1]), int(match[2])


def chunk_cost(plan: Plan, chunk: Chunk) -> float:
    """The cost model's upper estimate of one chunk [s] (every episode flying its whole ``t_max``)."""
    b = plan.blocks[(chunk.variant, chunk.family)]
    seen = seen_slots(b.sim, b.obstacles, b.agents)
    return b.settings * (chunk.stop - chunk.start) * b.sim.episode.steps * step_cost_us(b.mpc, seen, b.agents) * 1e-6


def shard_chunks(plan: Plan, shard: int, shards: int) -> tuple[Chunk, ...]:
    """The chunks of shard ``shard`` of ``shards``: the plan's chunks dealt by cost, the costliest first,
    each to the shard with the least cost so far (ties: the lower shard; Graham's LPT rule), in plan
    order. A function of the plan alone, so every process reading the same spec deals the same way."""
    import heapq

    chunks = plan.chunks
    cost = [chunk_cost(plan, c) for c in chunks]
    # (cost so far, shard): the least loaded, lower index first; shards past the number of chunks get none
    load = [(0.0, k) for k in range(min(shards, len(chunks)))]
    owner = {}
    for i in sorted(range(len(chunks)), key=lambda i: (-cost[i], i)):
        total, s = heapq.heappop(load)
        owner[i] = s
        heapq.heappush(load, (total + cost[i], s))
    return tuple(c for i, c in enumerate(chunks) if owner[i] == shard)


def describe_plan(plan: Plan) -> str:
    """What a run of ``plan`` does (``jaxapf sweep --dry-run``)."""
    from ..planners.apf import FUSED

    spec = plan.spec
    run_s, compile_s = plan.estimate_seconds()
    remaining = plan.episodes_of(plan.chunks)
    padding = plan.padding_note()
    lines = [
        f"sweep {spec.name} (spec_hash {spec.hash[:12]})",
        f"  settings:          {plan.settings}, in {len(plan.variants)} static variant(s)"
        + (f"; {plan.duplicates} repeat an earlier setting in every gain their method reads and are not simulated "
           "again (their rows copy it)" if plan.duplicates else ""),
        f"  families:          {len(spec.families)} ({', '.join(spec.families)}), {spec.fields} fields each, "
        f"seed {spec.seed}",
        f"  episodes:          {plan.episodes:,}" + (f" ({plan.episodes - remaining:,} already in the output, "
                                                    f"{remaining:,} to run)" if plan.done else ""),
        f"  compiled variants: {plan.static_variants} distinct (SimConfig, MPCConfig); {plan.programs} evaluate "
        f"program(s) with their shapes, each compiled once per device",
        f"  control steps:     up to {plan.control_steps():,} one after another on each device (the chunks in turn, "
        "each chunk's episodes queued on its slots)",
        f"  policy:            {plan.policy.name} (--policy): "
        + ("a quarter of each chunk's episodes side by side, each slot flying several in turn"
           if plan.policy.refill else "every episode of a chunk side by side, up to the vmap width")
        + (f"; every family padded to {plan.obstacle_slots} obstacle slots (one program per variant)"
           if plan.obstacle_slots is not None else "")
        + "".join(f"; {', '.join(name.split(FUSED))} fly one program" for name in plan.fused)
        + f"; --memory-budget {format_bytes(plan.memory_budget)}",
        f"  chunks:            {len(plan.chunks)} to run" + (f", {len(plan.done)} done" if plan.done else "")
        + f" (one Parquet part each), on {plan.devices} device(s), "
          f"vmap width {plan.width}, {plan.dtype}",
    ]
    for v in plan.variants:
        static = ", ".join(f"{k}={json.dumps(x)}" for k, x in v.static) or "defaults"
        for family in spec.families:
            b = plan.blocks[(v.index, family)]
            lines.append(f"    v{v.index:03d} {family:<13s} {static}: {b.settings} settings"
                         + (f" (of {len(v.settings)}; the others repeat one)" if v.duplicates else "")
                         + f" × {b.fields} fields per "
                         f"chunk (padded {b.padded}), {b.sim.episode.steps} steps, N={b.mpc.horizon}, I={b.mpc.iters}, "
                         f"M={b.obstacles}" + (f", A={b.agents}" if spec.swarm else "")
                         + (f", vmap width {b.width}" if b.width != plan.width else ""))
    lines += [
        f"  time estimate:     up to {format_seconds(run_s)} of simulation + up to {format_seconds(compile_s)} of "
        "compilation (~0 with a warm compilation cache)",
        "                     simulation: every episode flying its whole t_max; the engine stops each episode when it "
        "ends (goal, collision), which in the quick start's sweep cut the time to 0.62 of this (docs/performance.md)",
        "                     from a per-step cost model fitted on a 2-core x86-64 CPU (jaxapf.sweep.STEP_COST_US, "
        "±50 %; benchmarks/fit_cost.py refits it here); on accelerators it is only an upper bound",
        *([f"  padding:           {padding}"] if padding else []),
        f"  memory estimate:   {format_bytes(plan.peak_bytes)} per chunk + ~{format_bytes(PROCESS_BASELINE)} for the "
        "process (up to ~1 GiB more while XLA compiles); docs/sweep.md",
    ]
    return "\n".join(lines)


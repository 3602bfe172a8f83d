"""How a sweep fills a backend: how many episodes fly side by side, whether families share one program,
and how much memory a chunk may take (docs/performance.md, "A policy per backend").

Two policies, chosen by the backend and selectable on any (``jaxapf sweep --policy``), so the CPU shows
what the accelerator runs:

* :data:`CPU`: a quarter of a chunk's episodes fly side by side and each slot takes the next episode when
  its own ends (the slots stay busy on a few cores); each family keeps its own obstacle slot count, so no
  step computes padded slots; 256 MiB per chunk.
* :data:`ACCELERATOR`: every episode of a chunk flies side by side (a GPU step costs about the same from
  1,024 to 4,096 episodes: the device is launch-bound, not compute-bound), up to 65,536 at once; the
  families of a sweep are padded to one obstacle slot count, so one program serves them all; potential-field
  methods that differ only in their weight fly one program too (:func:`jaxapf.sweep.plan.fuse`); the chunk's
  budget is half the device's free memory.

Neither changes an episode's numbers through its width (the streaming engine's contract,
``tests/engine/test_stream.py``); padded obstacle slots contribute nothing but are summed in a different
order, and a fused program computes every weight and selects one (a program compiled apart), so
:data:`ACCELERATOR` rows agree with :data:`CPU` rows up to rounding (docs/testing.md).
"""

from __future__ import annotations

import dataclasses

import jax

from ..validation import ConfigError
from .batch import CPU_WIDTH

__all__ = ["Policy", "CPU", "ACCELERATOR", "POLICIES", "CPU_BUDGET", "policy_for", "free_memory", "available_memory"]


@dataclasses.dataclass(frozen=True)
class Policy:
    """How a sweep fills one kind of backend (hashable, static).

    Attributes:
      name: ``cpu`` or ``accelerator`` (``--policy``).
      refill: slots a quarter of a chunk's episodes, each flying several in turn
        (:func:`~jaxapf.engine.stream.stream_slots`); False: as many slots as the vmap width holds.
      common_slots: pad every family of a sweep to the largest obstacle slot count, so families share
        one compiled program per static variant.
      fuse: potential-field methods that differ only in their weight fly one program
        (:func:`jaxapf.sweep.plan.fuse`).
      width: the widest vmap of a sweep.
      budget: a chunk's default working-set budget [bytes]; ``None``: half the device's free memory
        (:func:`free_memory`).
      width_budget: the largest working set one vmapped batch may take [bytes]; ``None``: half the chunk's
        budget.
    """

    name: str
    refill: bool
    common_slots: bool
    width: int
    budget: int | None
    width_budget: int | None
    fuse: bool = False

    def memory_budget(self, free: int | None) -> int:
        """The default ``--memory-budget``: :attr:`budget`, or half of ``free`` device memory (256 MiB where
        the device does not say)."""
        if self.budget is not None:
            return self.budget
        return max(free // 2, CPU_BUDGET) if free else CPU_BUDGET

    def batch_budget(self, budget: int) -> int:
        """The largest working set of one vmapped batch under a chunk ``budget``."""
        return self.width_budget if self.width_budget is not None else budget // 2


#: The CPU's chunk budget, and the least an accelerator's default takes [bytes].
CPU_BUDGET = 256 * 2**20
CPU = Policy("cpu", refill=True, common_slots=False, width=CPU_WIDTH, budget=CPU_BUDGET, width_budget=CPU_BUDGET // 2)
ACCELERATOR = Policy("accelerator", refill=False, common_slots=True, width=65_536, budget=None, width_budget=None,
                     fuse=True)
POLICIES = {p.name: p for p in (CPU, ACCELERATOR)}


def policy_for(backend: str | None = None, name: str | None = None) -> Policy:
    """The policy ``name`` (``--policy``), or the one of ``backend`` (default this process's JAX backend)."""
    if name is not None:
        if name not in POLICIES:
            raise ConfigError(f"--policy = {name!r} must be one of {', '.join(POLICIES)}")
        return POLICIES[name]
    return CPU if (backend or jax.default_backend()) == "cpu" else ACCELERATOR


def free_memory(device: jax.Device | None = None) -> int | None:
    """Bytes free on ``device`` (default the first local one), from its allocator; ``None`` where it does not
    say (the CPU)."""
    stats = (device or jax.local_devices()[0]).memory_stats()
    if not stats or "bytes_limit" not in stats:
        return None
    return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))


def available_memory(device: jax.Device | None = None) -> int | None:
    """Bytes a computation on ``device`` (default the first local one) may still take: its free memory
    (:func:`free_memory`), or on the CPU the host's available memory (``MemAvailable``); None where neither
    says."""
    free = free_memory(device)
    if free is not None:
        return free
    try:
        with open("/proc/meminfo") as fh:
            found = next((line for line in fh if line.startswith("MemAvailable:")), None)
    except OSError:
        return None
    return int(found.split()[1]) * 1024 if found else None

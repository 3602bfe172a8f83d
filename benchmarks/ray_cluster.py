"""`jaxapf sweep --ray` on a local Ray cluster: its per-chunk overhead, and workers killed at random moments.

    python benchmarks/ray_cluster.py [--tries 10] [--seed 0] [--json]

A small sweep (2 families × 2 methods × 128 fields, chunks of 8 fields: 64 chunks) runs in this
process on one device (the reference rows, warm), then on a local Ray cluster of two CPU slots
started here:

- overhead: with one worker (it asks for both CPUs, so it has the cores the local run had) the
  median time between two parts written, against the local run's median (both warm, the first
  chunk of each program left out); the difference is what Ray adds per chunk (the call to the
  worker, moving the metrics back, the driver's bookkeeping). The default chunk of a study (the
  first chunk of ``sweeps/compare-small.toml`` as ``jaxapf sweep`` plans it, run twice here, the
  second timed) puts that overhead in proportion;
- faults: runs with two workers until ``--tries`` of them had one worker process killed with SIGKILL while it
  runs a chunk, at the first such moment after a random delay (uniform over 5–95 % of the time a
  clean run takes until its last part, starting the workers included; a run that ends first is
  kept and counted apart); after each, the
  output must be complete and sound (what ``jaxapf sweep verify`` judges) and the rows must equal the
  reference, bit for bit.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import random
import signal
import statistics
import sys
import tempfile
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPEC_TOML = """name = "ray"
[scenario]
families = ["trap", "crossing"]
fields = 128
seed = 21
[sim]
t_max = 10.0
horizon = 8
iters = 10
[grid]
method = ["basic", "direction_velocity"]
"""


def busy_workers() -> list[int]:
    """PIDs of the Ray worker processes running a chunk now (titled ``ray::ChunkWorker.run``) of the
    cluster this process started (its descendants: another process's cluster is left alone)."""
    def parent(pid: int) -> int:
        stat = pathlib.Path(f"/proc/{pid}/stat").read_text()
        return int(stat[stat.rindex(")") + 2:].split()[1])

    pids, me = [], os.getpid()
    for entry in pathlib.Path("/proc").iterdir():
        try:
            if not (entry.name.isdigit() and (entry / "cmdline").read_bytes().startswith(b"ray::ChunkWorker.run")):
                continue
            pid = int(entry.name)
            while pid > 1 and pid != me:
                pid = parent(pid)
            if pid == me:
                pids.append(int(entry.name))
        except (OSError, ValueError):
            continue
    return pids


def part_intervals(run) -> list[float]:
    """Seconds between consecutive parts written by ``run(after_part)``, the first part of each
    (variant, family) program left out (it may compile or load the program)."""
    stamps = []
    run(lambda chunk: stamps.append(((chunk.variant, chunk.family), time.perf_counter())))
    seen, out = set(), []
    for (key, t), (_, before) in zip(stamps[1:], stamps[:-1]):
        if key in seen:
            out.append(t - before)
        seen.add(key)
    return out


def default_chunk_s() -> float:
    """Seconds of the first chunk of sweeps/compare-small.toml as planned by default, on one device, warm."""
    from jaxapf.sweep import load_spec, plan_sweep
    from jaxapf.sweep.execute import ChunkRunner

    plan = plan_sweep(load_spec(ROOT / "sweeps" / "compare-small.toml"), devices=1)
    runner = ChunkRunner(plan)
    times = []
    for _ in range(2):
        start = time.perf_counter()
        metrics, _, _ = runner.dispatch(plan.chunks[0])
        [a.block_until_ready() for a in metrics.values()]
        times.append(time.perf_counter() - start)
    runner.close()
    return times[-1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tries", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    import ray

    from jaxapf.engine import configure_jax, default_cache_dir
    from jaxapf.sweep import load_spec, read_sweep, run_sweep
    from jaxapf.sweep.audit import audit_folder
    from jaxapf.sweep.cluster import RayCluster

    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR")  # before JAX starts its threads
    configure_jax(cache_dir=default_cache_dir(), cpu_devices=1)
    rng = random.Random(args.seed)
    result: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        (tmp / "ray.toml").write_text(SPEC_TOML)
        spec = load_spec(tmp / "ray.toml")
        sweep = dict(chunk_fields=8, quiet=True)

        def fresh(name: str) -> pathlib.Path:
            return tmp / f"{name}-{time.monotonic_ns()}"

        local = []
        for _ in range(2):  # the second is warm
            local = part_intervals(lambda after: run_sweep(spec, fresh("local"), devices=1, after_part=after, **sweep))
        reference = fresh("reference")
        run_sweep(spec, reference, devices=1, **sweep)
        rows, meta = read_sweep(reference)

        one_slot = []
        for _ in range(2):
            one_slot = part_intervals(lambda after: run_sweep(spec, fresh("one-slot"), ray=RayCluster(cpus=2),
                                                              after_part=after, **sweep))
        for _ in range(2):  # the second is warm
            start, last = time.perf_counter(), []
            run_sweep(spec, fresh("clean"), ray=RayCluster(),
                      after_part=lambda c, last=last: last.append(time.perf_counter()), **sweep)
            clean_s, chunks_s = time.perf_counter() - start, last[-1] - start  # the run; until its last part
        tries = []
        while sum(t["killed_a_busy_worker"] for t in tries) < args.tries and len(tries) < 3 * args.tries:
            out, killed = fresh("killed"), []
            delay, done = rng.uniform(0.05, 0.95) * chunks_s, threading.Event()

            def kill(delay=delay, killed=killed, done=done):
                time.sleep(delay)
                while not done.is_set():  # the first moment after the delay a worker is running a chunk
                    pids = busy_workers()
                    if pids:
                        os.kill(rng.choice(pids), signal.SIGKILL)
                        killed.append(True)
                        return
                    time.sleep(0.02)

            killer = threading.Thread(target=kill)
            start = time.perf_counter()
            killer.start()
            run_sweep(spec, out, ray=RayCluster(), **sweep)
            seconds = time.perf_counter() - start
            done.set()
            killer.join()
            found, _ = audit_folder(out)  # what `jaxapf sweep verify` judges
            tries.append({"killed_at_s": round(delay, 2), "killed_a_busy_worker": bool(killed),
                          "seconds": round(seconds, 2), "complete_and_sound": found.complete,
                          "rows_equal_one_process": bool(read_sweep(out)[0].equals(rows))})
        ray.shutdown()
        chunk_s = default_chunk_s()
    local_ms, ray_ms = 1e3 * statistics.median(local), 1e3 * statistics.median(one_slot)
    overhead_ms = ray_ms - local_ms
    result = {"chunks": meta["parts"], "episodes": int(len(rows)), "local_part_interval_ms": round(local_ms, 1),
              "ray_part_interval_ms": round(ray_ms, 1), "ray_overhead_per_chunk_ms": round(overhead_ms, 1),
              "default_chunk_s": round(chunk_s, 2),
              "overhead_of_default_chunk_percent": round(100 * overhead_ms / 1e3 / chunk_s, 2),
              "clean_two_slot_run_s": round(clean_s, 2),
              "median_killed_run_s": round(statistics.median(t["seconds"] for t in tries), 2), "tries": tries,
              "tries_killed_a_worker": sum(t["killed_a_busy_worker"] for t in tries),
              "tries_sound_and_equal": sum(t["complete_and_sound"] and t["rows_equal_one_process"]
                                           for t in tries)}
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))
    return 0 if result["tries_sound_and_equal"] == len(tries) and result["tries_killed_a_worker"] == args.tries else 1


if __name__ == "__main__":
    sys.exit(main())

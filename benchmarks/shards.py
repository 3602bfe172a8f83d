"""64 shards of one sweep on this machine, one after another, some killed and rerun: the same rows as one process.

    python benchmarks/shards.py [--shards 64] [--kill-every 8] [--seed 0] [--json]

A small sweep (2 families × 2 methods × 128 fields, chunks of 8 fields: 64 chunks) runs once in one
process (``jaxapf sweep``, warm compilation cache) and then as ``--shards`` separate ``jaxapf sweep
--shard I/N`` processes into one output, one after another in a shuffled order; every
``--kill-every``-th shard is killed with SIGKILL after a random delay and rerun. Then ``jaxapf sweep
verify`` must pass and the rows must equal the one-process run's, bit for bit. Printed: the wall
time of the one-process run and of the shard processes that ran to the end (a rerun of a killed
shard computes only its missing parts), and the overhead per shard process over the one-process
run's share (its start, imports, plan and audit of the output).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import random
import signal
import subprocess
import sys
import tempfile
import time

SPEC_TOML = """name = "shards"
[scenario]
families = ["trap", "crossing"]
fields = 128
seed = 21
[sim]
t_max = 3.0
horizon = 4
iters = 4
[grid]
method = ["basic", "direction_velocity"]
"""


def _sweep(spec: pathlib.Path, out: pathlib.Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "jaxapf", "sweep", str(spec), "--out", str(out), "--quiet", "--chunk-fields", "8",
            *extra]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shards", type=int, default=64)
    p.add_argument("--kill-every", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    rng = random.Random(args.seed)
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        spec = tmp / "shards.toml"
        spec.write_text(SPEC_TOML)
        subprocess.run(_sweep(spec, tmp / "warm"), check=True, env=env)  # fills the compilation cache
        start = time.perf_counter()
        subprocess.run(_sweep(spec, tmp / "one"), check=True, env=env)
        one = time.perf_counter() - start
        order = list(range(args.shards))
        rng.shuffle(order)
        killed, sharded = 0, 0.0  # the wall time of the shard processes that ran to the end
        for n, shard in enumerate(order):
            command = _sweep(spec, tmp / "sharded", "--shard", f"{shard}/{args.shards}")
            if args.kill_every and n % args.kill_every == 0:
                proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                time.sleep(rng.uniform(0.5, 4.0))
                proc.send_signal(signal.SIGKILL)
                proc.wait()
                killed += 1
            start = time.perf_counter()
            subprocess.run(command, check=True, env=env, stdout=subprocess.DEVNULL)
            sharded += time.perf_counter() - start
        verify = subprocess.run([sys.executable, "-m", "jaxapf", "sweep", "verify", str(tmp / "sharded")],
                                capture_output=True, text=True, env=env)
        from jaxapf.sweep import read_sweep

        a, _ = read_sweep(tmp / "one")
        b, meta = read_sweep(tmp / "sharded")
        equal = a.equals(b)
    result = {"shards": args.shards, "parts": meta["parts"], "episodes": int(len(b)), "killed_and_rerun": killed,
              "one_process_s": round(one, 2), "shard_processes_s": round(sharded, 2),
              "overhead_per_shard_s": round((sharded - one) / args.shards, 2),
              "verify_exit_status": verify.returncode, "rows_equal_one_process": bool(equal)}
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))
    return 0 if equal and verify.returncode == 0 else 1


if __name__ == "__main__":
    sys.exit(main())

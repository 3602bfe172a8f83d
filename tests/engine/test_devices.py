"""DeviceBatch: the fields' blocks on several CPU devices, concurrently unless the planner forbids it."""

import os
import subprocess
import sys
import textwrap

import pytest

_SCRIPT = textwrap.dedent("""
    import threading, time
    import jax, jax.numpy as jnp
    from jaxapf import Gains, MPCConfig, SimConfig
    from jaxapf.engine.devices import DeviceBatch
    from jaxapf.scenarios import family_params, make_scenarios

    assert jax.local_device_count() == 2, jax.devices()
    fields = make_scenarios(0, family_params("trap"), 4)
    gains = jax.tree_util.tree_map(lambda g: jnp.asarray(g, jnp.float32)[None], Gains())
    for method in ("basic", "keepout_mpc"):
        running, most = [0], [0]
        lock = threading.Lock()

        def program(s, g, sim, mpc, width, metrics, refill=True):
            with lock:
                running[0] += 1
                most[0] = max(most[0], running[0])
            time.sleep(0.5)
            with lock:
                running[0] -= 1
            return {m: s.start[None, :, 0] * 0 for m in metrics}  # on the block's device

        with DeviceBatch(jax.local_devices()) as batch:
            out = batch.evaluate(fields, batch.put_gains(gains), SimConfig.from_flat(method=method), MPCConfig(),
                                 2, ("success",), program)
        assert out["success"].shape == (1, 4)
        print(method, most[0])
""")


@pytest.mark.slow
def test_a_planner_that_forbids_it_runs_the_devices_blocks_one_after_another():
    """``basic`` runs its two CPU devices' blocks at once; ``keepout_mpc`` (``concurrent_cpu_devices =
    False``: two such programs at once stall XLA's CPU runtime) one after another."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    done = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split() == ["basic", "2", "keepout_mpc", "1"]

"""``jaxapf sweep --policy``: the accelerator's policy chosen on the CPU writes the CPU policy's rows (up to
rounding: families padded to one slot count, potential-field methods fused in one program), in fewer programs."""

import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest
from conftest import assert_same_episodes

from jaxapf.cli import main
from jaxapf.datatypes.obstacles import Obstacles, clearance
from jaxapf.engine import evaluate_program
from jaxapf.engine.policy import ACCELERATOR, CPU, free_memory, policy_for
from jaxapf.engine.stream import SEGMENT
from jaxapf.sweep import parse_spec, plan_sweep, read_sweep, run_sweep
from jaxapf.sweep.plan import describe_plan
from jaxapf.validation import ConfigError


def _spec(families=("crossing",), fields=40, methods=("basic", "direction_velocity")):
    return parse_spec({"name": "policy", "scenario": {"families": list(families), "fields": fields, "seed": 2},
                       "sim": {"t_max": 6.0}, "grid": {"method": list(methods)}})


def test_the_backend_picks_the_policy_and_the_option_overrides_it():
    assert policy_for("cpu") is CPU and policy_for("gpu") is ACCELERATOR and policy_for("tpu") is ACCELERATOR
    assert policy_for("gpu", "cpu") is CPU and policy_for("cpu", "accelerator") is ACCELERATOR
    with pytest.raises(ConfigError, match=r"--policy = 'fast' must be one of cpu, accelerator"):
        policy_for("cpu", "fast")


def test_the_accelerators_budget_is_half_its_free_memory():
    assert CPU.memory_budget(80 * 2**30) == 256 * 2**20  # the CPU's is fixed
    assert ACCELERATOR.memory_budget(80 * 2**30) == 40 * 2**30
    assert ACCELERATOR.memory_budget(None) == ACCELERATOR.memory_budget(100 * 2**20) == 256 * 2**20  # floor
    assert free_memory() is None  # the CPU's allocator does not say
    assert ACCELERATOR.batch_budget(2**30) == 2**29 and CPU.batch_budget(2**30) == CPU.width_budget


def test_padded_obstacle_slots_are_invalid_and_change_no_clearance():
    fields = _spec().family_params("crossing")
    from jaxapf.scenarios import make_scenarios

    obstacles = make_scenarios(0, fields, 3).obstacles
    padded = obstacles.padded(7)
    assert padded.position.shape == (3, 7, 3) and padded.valid.shape == (3, 7)
    assert not np.asarray(padded.valid[:, 3:]).any()
    assert obstacles.padded(3) is obstacles and obstacles.padded(2) is obstacles
    one = jax.tree_util.tree_map(lambda x: x[0], obstacles)
    p = np.array([1.0, 2.0, 1.0], np.float32)
    near = clearance(p, one, 0.5, 0.2)
    wide = clearance(p, one.padded(7), 0.5, 0.2)
    np.testing.assert_array_equal(wide[:3], near)
    assert np.isinf(np.asarray(wide[3:])).all()
    swarm_like = Obstacles(**{**one.__dict__, "agent": np.zeros(3, bool)}).padded(5)
    assert swarm_like.agent.shape == (5,) and not np.asarray(swarm_like.agent).any()


def test_dry_run_counts_programs_and_sequential_steps_by_hand():
    """2 methods × 2 families (crossing 3 slots, overtake 2), 40 fields, 60 steps: the CPU policy compiles a
    program per (method, slot count), 4; the accelerator's pads overtake to 3 slots and flies both methods in one
    fused program, 1. 40 episodes a chunk: the CPU's 64 slots (the narrowest) and the accelerator's fly all 40 at
    once, so 60 steps per chunk."""
    spec = _spec(("crossing", "overtake"))
    cpu, acc = (plan_sweep(spec, devices=1, policy=p) for p in ("cpu", "accelerator"))
    assert (cpu.programs, acc.programs) == (4, 1)
    assert {b.obstacles for b in acc.blocks.values()} == {3} and acc.obstacle_slots == 3
    assert cpu.obstacle_slots is None and "obstacle_slots" not in cpu.meta and acc.meta["obstacle_slots"] == 3
    assert acc.fused == ("basic+direction_velocity",) and acc.meta["fused"] == ["basic+direction_velocity"]
    assert {(b.fused, b.choice) for b in cpu.blocks.values()} == {("", 0)} and "fused" not in cpu.meta
    assert {b.choice for (v, _), b in acc.blocks.items() if v == 1} == {1}  # direction_velocity's weight
    np.testing.assert_array_equal(acc.gains(acc.variants[1])["weight_choice"], [1.0])
    assert "weight_choice" not in cpu.gains(cpu.variants[1])
    one = plan_sweep(_spec(), devices=1, policy="accelerator")  # one slot count: nothing padded, nothing recorded
    assert one.obstacle_slots is None and "obstacle_slots" not in one.meta
    assert cpu.control_steps() == acc.control_steps() == 4 * SEGMENT * 6
    text = describe_plan(acc)
    assert "1 evaluate program(s)" in text and "every family padded to 3 obstacle slots" in text
    assert "basic, direction_velocity fly one program" in text
    assert "policy:            accelerator" in text and "policy:            cpu" in describe_plan(cpu)


def test_only_methods_alike_but_in_their_weight_fuse():
    """A vortex (an extra force term) and MPPI (its own plan) keep their programs; a method at two conventions
    (a static setting) fuses with the others at each convention apart."""
    spec = parse_spec({"name": "f", "scenario": {"families": ["crossing"], "fields": 8, "seed": 0},
                       "sim": {"t_max": 4.0}, "grid": {"method": ["basic", "direction", "vortex", "mppi"],
                                                       "convention": ["intent", "literal"]}})
    acc = plan_sweep(spec, devices=1, policy="accelerator")
    fused = {dict(v.static)["method"] + "/" + dict(v.static)["convention"]: acc.blocks[(v.index, "crossing")].fused
             for v in acc.variants}
    assert fused == {"basic/intent": "basic+direction", "direction/intent": "basic+direction",
                     "basic/literal": "basic+direction", "direction/literal": "basic+direction",
                     "vortex/intent": "", "vortex/literal": "", "mppi/intent": "", "mppi/literal": ""}
    assert acc.programs == 2 + 4  # the fused pair at each convention, vortex and mppi at each


def test_a_wide_chunk_is_one_round_on_the_accelerator_and_several_on_the_cpu():
    """1,024 episodes a chunk at width 1,024: the CPU policy flies them on 256 slots, 4 rounds of 60 steps;
    the accelerator's on 1,024, one round."""
    spec = _spec(fields=1024, methods=("basic",))
    cpu, acc = (plan_sweep(spec, devices=1, policy=p, width=1024) for p in ("cpu", "accelerator"))
    assert len(cpu.chunks) == len(acc.chunks) == 1
    assert (cpu.control_steps(), acc.control_steps()) == (4 * 60, 60)


@pytest.mark.slow
def test_the_policies_write_the_same_rows(tmp_path):
    """One slot count (crossing alone): the accelerator flies both methods in one fused program, compiled apart,
    so its rows round apart from the CPU's, within what assert_same_episodes allows. Two slot counts: overtake's
    fields fly with a padded slot in the same fused program, compiled once for both families. The fusing and the
    padding are recorded, so the outputs are not mixed."""
    one = _spec()
    a = read_sweep(run_sweep(one, tmp_path / "cpu", quiet=True, policy="cpu").out)[0]
    b = read_sweep(run_sweep(one, tmp_path / "acc", quiet=True, policy="accelerator").out)[0]
    assert_same_episodes(a, b, 0.1)
    two = _spec(("crossing", "overtake"))
    before = evaluate_program.compiled()
    c = read_sweep(run_sweep(two, tmp_path / "cpu2", quiet=True, policy="cpu").out)[0]
    between = evaluate_program.compiled()
    d = read_sweep(run_sweep(two, tmp_path / "acc2", quiet=True, policy="accelerator").out)[0]
    # the CPU compiled overtake's two programs (crossing's were compiled above); the accelerator none: its
    # padded overtake fields fly the fused program crossing's compiled
    assert (between - before, evaluate_program.compiled() - between) == (2, 0)
    assert_same_episodes(c, d, 0.1)
    with pytest.raises(ConfigError, match="different sweep"):
        run_sweep(two, tmp_path / "acc2", quiet=True, policy="cpu")
    with pytest.raises(ConfigError, match="different sweep"):
        run_sweep(one, tmp_path / "acc", quiet=True, policy="cpu")


_DEVICES = textwrap.dedent("""
    import sys
    from jaxapf.sweep import parse_spec, read_sweep, run_sweep
    spec = parse_spec({"name": "d", "scenario": {"families": ["crossing", "overtake"], "fields": 24, "seed": 1},
                       "sim": {"t_max": 4.0}, "grid": {"method": ["direction_velocity"]}})
    one = read_sweep(run_sweep(spec, sys.argv[1] + "/one", quiet=True, devices=1, policy="accelerator").out)[0]
    two = read_sweep(run_sweep(spec, sys.argv[1] + "/two", quiet=True, devices=2, policy="accelerator").out)[0]
    assert one.equals(two), "the rows differ with the device count"
    print("same")
""")


@pytest.mark.slow
def test_the_accelerator_policy_spreads_over_devices_with_the_same_rows(tmp_path):
    """``--devices 2`` (two forced host devices standing in for two GPUs): the rows of one device, bit for bit."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    done = subprocess.run([sys.executable, "-c", _DEVICES, str(tmp_path)], env=env, capture_output=True, text=True,
                          timeout=400)
    assert done.returncode == 0 and done.stdout.split() == ["same"], done.stderr[-3000:]


def test_a_bad_policy_is_one_line(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text('name = "s"\n[scenario]\nfamilies = ["crossing"]\nfields = 4\n')
    with pytest.raises(SystemExit) as exit_:
        main(["sweep", str(spec), "--policy", "fast", "--dry-run"])
    assert exit_.value.code == 2 and "invalid choice: 'fast'" in capsys.readouterr().err

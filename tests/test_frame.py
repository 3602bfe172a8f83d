"""The notebook API: jaxapf.evaluate_frame (fields × gain settings → a sweep's rows as a DataFrame),
Gains.grid / Gains.paired, Scenario.take."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxapf
from jaxapf.gains import setting_count

SIM = jaxapf.SimConfig.from_flat(method="direction_velocity", t_max=3.0)
MPC = jaxapf.MPCConfig(horizon=4, iters=4)
METRICS = ("success", "collision", "min_clearance", "path_length", "time_to_goal", "steps")


def test_grid_is_the_product_and_paired_pairs():
    grid = jaxapf.Gains.grid(gamma=[0.0, 2.0], k=[0.0, 0.5, 1.0])
    assert setting_count(grid) == 6
    np.testing.assert_array_equal(grid.gamma, [0, 0, 0, 2, 2, 2])  # the last key fastest, as a spec's [grid]
    np.testing.assert_array_equal(grid.k, [0, 0.5, 1, 0, 0.5, 1])
    assert grid.k_rep == jaxapf.GAINS.get("k_rep").default
    paired = jaxapf.Gains.paired(gamma=[0, 3], k=[0, 1])
    assert setting_count(paired) == 2 and setting_count(jaxapf.Gains()) == 1
    np.testing.assert_array_equal(jaxapf.Gains(gamma=[0, 3], k=[0, 1]).k, paired.k)
    assert isinstance(jaxapf.Gains(gamma=[1, 2]).gamma, np.ndarray)  # one leaf per gain, not a list of leaves


@pytest.mark.parametrize("call, message", [
    (lambda: jaxapf.Gains.paired(gamma=[0, 3], k=[0, 1, 0.5]), "different numbers of values (gamma 2, k 3)"),
    (lambda: jaxapf.Gains.grid(gamma=[]), "must be a non-empty list"),
    (lambda: jaxapf.Gains.grid(gamma=[-1.0]), "out of range"),
    (lambda: jaxapf.Gains.grid(nope=[1.0]), "nope is not a gain"),
    (lambda: jaxapf.evaluate_frame("trap", jaxapf.Gains(gamma=[0, 1], k=[0, 1, 0.5]), fields=2), "Gains.grid"),
    (lambda: jaxapf.evaluate_frame("nowhere", fields=2), "nowhere"),
    (lambda: jaxapf.evaluate_frame("trap", fields=0), "fields = 0"),
    (lambda: jaxapf.evaluate_frame("trap", {"gamma": 1.0}, fields=2), "must be a Gains"),
    (lambda: jaxapf.evaluate_frame("trap", metrics=["speed"], fields=2), "speed"),
    (lambda: jaxapf.evaluate(jaxapf.make_scenarios(0, jaxapf.family_params("trap"), 2),
                             jaxapf.Gains(gamma=[0, 1], k=[0.5]), SIM, MPC), "different numbers of values"),
    (lambda: jaxapf.make_scenarios(0, jaxapf.family_params("trap"), 2).take(2), "out of range"),
])
def test_bad_input_is_one_line(call, message):
    with pytest.raises(jaxapf.ConfigError) as err:
        call()
    assert message in str(err.value) and "\n" not in str(err.value)


def test_take_is_one_field_of_the_batch():
    fields = jaxapf.make_scenarios(5, jaxapf.family_params("trap"), 3)
    one = fields.take(1)
    again = jaxapf.make_scenarios(5, jaxapf.family_params("trap"), [1]).take(0)
    assert one.start.shape == (3,) and fields.take(slice(0, 2)).start.shape == (2, 3)
    for a, b in zip(jax.tree_util.tree_leaves(one), jax.tree_util.tree_leaves(again), strict=True):
        np.testing.assert_array_equal(a, b)


def test_frame_is_evaluate_with_labels():
    """A 2 × 3 grid on 3 fields: the rows are evaluate's arrays exactly, settings-major, labelled."""
    gains = jaxapf.Gains.grid(gamma=[0.0, 2.0], k=[0.0, 0.5, 1.0])
    df = jaxapf.evaluate_frame("trap", gains, SIM, MPC, fields=3, seed=7, metrics=METRICS)
    fields = jaxapf.make_scenarios(7, jaxapf.family_params("trap"), 3)
    arrays = jaxapf.evaluate(fields, gains, SIM, MPC, metrics=METRICS)
    assert len(df) == 18
    for m in METRICS:
        np.testing.assert_array_equal(df[m].to_numpy().reshape(6, 3), np.asarray(arrays[m]), err_msg=m)
        assert df[m].dtype == np.asarray(arrays[m]).dtype, m
    np.testing.assert_array_equal(df["setting"], np.repeat(np.arange(6), 3))
    np.testing.assert_array_equal(df["field"], np.tile(np.arange(3), 6))
    np.testing.assert_array_equal(df["gamma"], np.repeat([0.0, 0.0, 0.0, 2.0, 2.0, 2.0], 3))
    np.testing.assert_array_equal(df["k"], np.repeat([0.0, 0.5, 1.0, 0.0, 0.5, 1.0], 3))
    kinds = np.asarray(jaxapf.FAMILIES.get("trap").kinds)[np.asarray(fields.kind)]
    np.testing.assert_array_equal(df["kind"], np.tile(kinds, 6))
    assert set(df["family"]) == {"trap"} and set(df["seed"]) == {7} and set(df["method"]) == {"direction_velocity"}
    assert set(df["t_max"]) == {3.0} and set(df["horizon"]) == {4}
    from jaxapf.sweep import row_config

    cfg = row_config(df.attrs["jaxapf"], df.iloc[10])  # setting 3 (γ 2, k 0), field 1
    assert (cfg.field, cfg.gains.gamma, cfg.gains.k, cfg.sim, cfg.mpc) == (1, 2.0, 0.0, SIM, MPC)


@pytest.mark.slow
def test_frame_has_a_sweeps_columns(tmp_path):
    """The same study as a sweep spec: the same columns, dtypes and ids, and the same episodes."""
    from conftest import assert_same_episodes

    from jaxapf.metrics import METRICS as REGISTRY
    from jaxapf.sweep import parse_spec, read_sweep, run_sweep

    spec = parse_spec({
        "name": "frame-twin",
        "scenario": {"families": ["crossing"], "fields": 3, "seed": 2, "params": {"crossing": {"speed": [0.5, 1.0]}}},
        "sim": {"method": "direction_velocity", "t_max": 3.0, "horizon": 4, "iters": 4, "q_pos": [1.0, 1.0, 2.0]},
        "gains": {"k_rep": 8.0},
        "grid": {"gamma": [0.0, 2.0], "k": [0.0, 0.5, 1.0]},
    })
    run_sweep(spec, tmp_path / "out", quiet=True)
    rows, _ = read_sweep(tmp_path / "out")
    df = jaxapf.evaluate_frame(jaxapf.family_params("crossing", speed=(0.5, 1.0)),
                               jaxapf.Gains.grid(gamma=[0.0, 2.0], k=[0.0, 0.5, 1.0]).replace(k_rep=8.0),
                               SIM, jaxapf.MPCConfig(horizon=4, iters=4, q_pos=(1.0, 1.0, 2.0)), fields=3, seed=2,
                               solvable=True)
    assert list(df.columns) == list(rows.columns)
    assert dict(df.dtypes) == dict(rows.dtypes)
    ids = [c for c in rows.columns if c not in REGISTRY]
    assert {"setting", "family", "kind", "field", "seed", "solvable", "gamma", "k", "k_rep", "q_pos"} <= set(ids)
    assert df[ids].equals(rows[ids])
    assert_same_episodes(df, rows, SIM.episode.dt)

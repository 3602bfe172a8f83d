"""``jaxapf sweep``: spec validation, chunking determinism, resume, refusal, sharding, Parquet layout."""

import copy
import dataclasses
import json
import os
import pathlib
import re
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import assert_same_episodes, changed

from jaxapf.cli import main
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.engine import default_width
from jaxapf.gains import Gains
from jaxapf.metrics import METRICS
from jaxapf.sweep import (
    DEFAULT_MEMORY_BUDGET,
    Chunk,
    SweepSpec,
    load_spec,
    parse_spec,
    plan_sweep,
    read_sweep,
    row_config,
    run_sweep,
)
from jaxapf.sweep.plan import WIDTH_BUDGET, describe_plan, working_set_bytes
from jaxapf.validation import BoundWarning, ConfigError

# Tiny but complete: two families sharing one obstacle-slot count (so one program per method),
# two static variants (methods) × two gains; 20 steps, N = 3, I = 3.
TINY = {
    "name": "tiny",
    "scenario": {"families": ["trap", "crossing"], "fields": 6, "seed": 1,
                 "params": {"trap": {"distance": [4.0, 6.0]}, "crossing": {"max_obstacles": 5}}},
    "sim": {"t_max": 2.0, "horizon": 3, "iters": 3},
    "gains": {"k_rep": 5.0},
    "grid": {"method": ["basic", "direction_velocity"], "gamma": [0.0, 1.0]},
}
ROWS = 4 * 2 * 6


def _spec(**changes) -> SweepSpec:
    return parse_spec(changed(TINY, **changes))


def _toml(path: pathlib.Path, data: dict) -> pathlib.Path:
    def value(v):
        return json.dumps(v)  # numbers, strings, lists: JSON and TOML agree

    lines = [f"name = {value(data['name'])}"]
    for table in ("scenario", "sim", "gains", "grid", "random"):
        if table in data:
            flat = {k: v for k, v in data[table].items() if not isinstance(v, dict)}
            lines += [f"[{table}]"] + [f"{k} = {value(v)}" for k, v in flat.items()]
            for sub, inner in data[table].items():
                if isinstance(inner, dict):
                    for fam, params in inner.items():
                        lines += [f"[{table}.{sub}.{fam}]"] + [f"{k} = {value(v)}" for k, v in params.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny sweep in one go (default chunking): rows and metadata."""
    out = tmp_path_factory.mktemp("ref") / "tiny.parquet"
    result = run_sweep(_spec(), out, quiet=True)
    assert result.episodes == ROWS and result.skipped == 0
    df, meta = read_sweep(out)
    return out, df, meta


# --------------------------------------------------------------------------------------------
# spec validation: every bad key gets its message, before anything runs
# --------------------------------------------------------------------------------------------

BAD = {
    "top-level key": ({"nmae": "x"},
                      "nmae is not a known key (did you mean `name`?); allowed: name, plugins, scenario"),
    "name": ({"name": "a b"}, "name = 'a b' must be a string"),
    "scenario key": ({"scenario.feilds": 3}, "scenario.feilds is not a known key"),
    "family": ({"scenario.families": ["trap", "forest"]},
               "scenario.families[1] = 'forest' is not a family or variant"),
    "variant of nothing": ({"scenario.families": ["trap", "crossing", "fast"],
                            "scenario.params.fast": {"family": "forest"}},
                           "scenario.params.fast.family = 'forest' is not allowed; choose one of paper_static"),
    "variant param": ({"scenario.families": ["trap", "crossing", "fast"],
                       "scenario.params.fast": {"family": "crossing", "sped": [1.0, 2.0]}},
                      "scenario.params.fast.sped is not a parameter of crossing"),
    "family renamed": ({"scenario.params.trap.family": "clutter"},
                       "scenario.params.trap.family = 'clutter': trap is a registered family"),
    "no family": ({"scenario.families": []}, "scenario.families = [] must list one or more of"),
    "fields type": ({"scenario.fields": "6"}, "scenario.fields = '6' must be an integer"),
    "fields range": ({"scenario.fields": 0}, "scenario.fields = 0 is out of range"),
    "seed": ({"scenario.seed": -1}, "scenario.seed = -1 is out of range"),
    "family param": ({"scenario.params.trap.obstacles": 8},
                     "scenario.params.trap.obstacles is not a parameter of trap"),
    "family param range": ({"scenario.params.trap.offset": -1.0},
                           "scenario.params.trap.offset = -1.0 is out of range"),
    "params of unlisted family": ({"scenario.params.clutter.density": 2.0},
                                  "scenario.params.clutter is not one of scenario.families"),
    "sim key": ({"sim.horizn": 3}, "sim.horizn is not a known key"),
    "sim type": ({"sim.dt": "0.1"}, "sim.dt = '0.1' must be a number"),
    "sim int": ({"sim.iters": 3.0}, "sim.iters = 3.0 must be an integer"),
    "sim range": ({"sim.v_max": -2.0}, "sim.v_max = -2.0 is out of range; allowed: a finite number > 0"),
    "sim bool": ({"sim.reference_velocity": 1}, "sim.reference_velocity = 1 must be true or false"),
    "gains key": ({"gains.gama": 1.0}, "gains.gama is not a known key"),
    "gains type": ({"gains.k_rep": True}, "gains.k_rep = True must be a number"),
    "gains range": ({"gains.d_s": 0.0}, "gains.d_s = 0.0 is out of range; allowed: a finite number > 0"),
    "grid key": ({"grid.gama": [1.0]}, "grid.gama is not a known key"),
    "grid empty": ({"grid.gamma": []}, "grid.gamma is empty"),
    "grid not a list": ({"grid.gamma": 1.0}, "grid.gamma = 1.0 must be a list"),
    "grid range": ({"grid.gamma": [0.0, 1.0, -1]},
                   "grid.gamma[2] = -1.0 is out of range; allowed: a finite number >= 0"),
    "grid method": ({"grid.method": ["basic", "magic"]},
                    "grid.method[1] = 'magic' is not a registered planner; choose one of"),
    "grid a_max": ({"grid.a_max": [1.0, 0.0]}, "grid.a_max[1] = 0.0 is out of range; allowed: a finite number > 0"),
    "grid vs sim": ({"grid.horizon": [3, 5]}, "grid.horizon is also set in [sim]"),
    "sim int range": ({"sim.iters": 0}, "sim.iters = 0 is out of range; allowed: an integer >= 1"),
    "grid weight": ({"grid.q_pos": [[1.0, 2.0]]}, "grid.q_pos[0] = [1.0, 2.0] must be a number or a list of 3"),
    "grid repeat": ({"grid.gamma": [1.0, 1]}, "grid.gamma[1] = 1 repeats an earlier value"),
    "grid vs gains": ({"gains.gamma": 1.0}, "grid.gamma is also set in [gains]"),
    "cross-field": ({"grid.dt": [0.1, 5.0]}, "sim.t_max = 2.0 must be at least one step (sim.dt = 5.0)"),
    "random n": ({"random.gamma": [0.0, 1.0]}, "random.n is missing"),
    "random key": ({"random.n": 4, "random.horizon": [3, 5]}, "random.horizon is not a gain"),
    "random vs grid": ({"random.n": 4, "random.gamma": [0.0, 1.0]}, "random.gamma is also set in [grid]"),
    "random range": ({"random.n": 4, "random.k": [0.8, 0.2]}, "random.k = [0.8, 0.2] is not a range"),
    "random log": ({"random.n": 4, "random.k": {"range": [0.0, 1.0], "log": True}},
                   "random.k.range[0] = 0.0 is out of range; allowed: > 0 for a log range"),
    "random table": ({"random.n": 4, "random.k": {"rng": [0.0, 1.0]}}, "random.k.rng is not a known key"),
    "random empty": ({"random.n": 4}, "random has no gain to sample"),
    "static mpc weights": ({"sim.mpc_weights": "static", "grid.mpc_pos": [0.5, 2.0]},
                           "sim.mpc_weights = 'static' compiles the MPC's weights in, but the spec sets mpc_pos"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_spec_names_the_key(case):
    changes, message = BAD[case]
    with pytest.raises(ConfigError) as info:
        _spec(**changes)
    assert message in str(info.value)


def test_bad_toml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(ConfigError, match="is not valid TOML"):
        load_spec(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        load_spec(tmp_path / "nope.toml")


def test_cli_reports_a_bad_spec_in_one_line_with_status_2(tmp_path, capsys):
    data = copy.deepcopy(TINY)
    data["grid"]["gamma"] = [0.0, -1.0]
    rc = main(["sweep", str(_toml(tmp_path / "bad.toml", data)), "--no-cache", "--devices", "1", "--dry-run"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert err[0].startswith("jaxapf sweep: error: grid.gamma[1] = -1.0 is out of range")


def test_expansion_order_random_samples_and_gains_file(tmp_path):
    random_k = {"random.n": 3, "random.k": {"range": [0.1, 10.0], "log": True}, "random.seed": 5}
    with pytest.warns(BoundWarning, match=r"random\.k\.range\[1\] = 10\.0 > 1: the paper's bound"):
        spec = _spec(**random_k)
    settings = spec.settings()
    assert len(settings) == 2 * 2 * 3
    # grid product in spec order (method outer, gamma inner), samples innermost and shared by grid points
    assert [dict(s.static)["method"] for s in settings[:6]] == ["basic"] * 6
    assert [s.gains["gamma"] for s in settings[:6]] == [0.0] * 3 + [1.0] * 3
    ks = [s.gains["k"] for s in settings[:3]]
    assert [s.gains["k"] for s in settings[3:6]] == ks and all(0.1 <= k <= 10.0 for k in ks)
    with pytest.warns(BoundWarning):
        assert spec.random_samples() == _spec(**random_k).random_samples()
    # --gains FILE: its values on top of [gains] (the gains either names become fixed), the swept gamma
    # untouched, every other gain at its default
    gains_file = tmp_path / "tuned.toml"
    gains_file.write_text("gamma = 9.0\nd_s = 3.5\n")
    tuned = parse_spec(copy.deepcopy(TINY), gains_file)
    assert tuned.gains == {"k_rep": 5.0, "d_s": 3.5}
    assert {s.gains["gamma"] for s in tuned.settings()} == {0.0, 1.0}
    assert {(s.gains["k"], s.gains["eta"]) for s in tuned.settings()} == {(0.5, 0.5)}
    assert tuned.hash != _spec().hash


# --------------------------------------------------------------------------------------------
# output layout
# --------------------------------------------------------------------------------------------


def test_parquet_schema_and_metadata(reference):
    out, df, meta = reference
    parts = sorted(p.name for p in out.iterdir())
    assert parts and all(Chunk.from_name(p) is not None for p in parts)
    schema = pq.read_schema(out / parts[0])
    gains = ["gamma", "k", "k_rep", "d_s", "k_att", "eta"]
    assert schema.names == ["setting", "method", "convention", *gains, "t_max", "horizon", "iters",
                            "family", "kind", "field", "seed", "solvable", *METRICS]
    types = dict(zip(schema.names, schema.types))
    assert types["setting"] == pa.int32() and types["field"] == pa.int64() and types["seed"] == pa.int64()
    assert all(types[c] == pa.string() for c in ("method", "convention", "family", "kind"))
    assert all(types[g] == pa.float64() for g in gains) and types["t_max"] == pa.float64()
    assert types["horizon"] == pa.int64() and types["iters"] == pa.int64()
    assert all(types[m] == pa.bool_() for m in ("solvable", "success", "collision", "stalled"))
    assert types["steps"] == pa.int32()
    assert types["min_clearance"] == pa.float32()
    assert {"format", "spec", "spec_hash", "versions", "prng", "dtype"} <= set(meta)
    assert meta["format"] == "jaxapf.sweep/2" and meta["dtype"] == "float32"
    assert meta["spec_hash"] == _spec().hash and SweepSpec.from_json(meta["spec"]) == _spec()
    assert meta["prng"]["field_key"] == "fold_in(key(seed), field)"
    assert meta["complete"] and meta["rows_expected"] == ROWS == len(df)
    # one row per (setting, family, field), same fields for every setting (common random numbers)
    assert not df.duplicated(["setting", "family", "field"]).any()
    assert sorted(df["setting"].unique()) == [0, 1, 2, 3]
    assert (df.groupby(["setting", "family"]).size() == 6).all()
    assert list(df.loc[df.setting == 2, "method"].unique()) == ["direction_velocity"]


def test_solvable_column_is_the_oracle_on_each_field(reference, tmp_path):
    from jaxapf.scenarios import make_scenarios, solvable

    _, df, _ = reference
    spec = _spec()
    sim = SimConfig.from_flat(t_max=2.0)
    for family in spec.families:
        fields = make_scenarios(spec.seed, spec.family_params(family), np.arange(spec.fields))
        want = solvable(fields, r_uav=sim.vehicle.r_uav, v_max=sim.vehicle.v_max, t_max=2.0, r_goal=sim.episode.r_goal)
        for _, rows in df[df.family == family].groupby("setting"):
            np.testing.assert_array_equal(rows.sort_values("field")["solvable"].to_numpy(bool), want)
    # 2 s at 2 m/s cannot cover a 4-6 m trap: the oracle says so (a proof), whatever the planner
    assert not df.loc[df.family == "trap", "solvable"].any()
    out = tmp_path / "no-oracle.parquet"
    run_sweep(_spec(**{"scenario.oracle": False}), out, quiet=True)
    assert "solvable" not in pq.read_schema(next(out.glob("part-*.parquet"))).names


def _explicit_spec() -> dict:
    data = copy.deepcopy(TINY)
    del data["grid"]
    data["setting"] = [
        {"method": "basic", "d_s": 3.0, "tags": {"role": "tuned", "selection_seed": 0}},
        {"method": "direction_velocity", "gamma": 2.0, "k": 0.25, "tags": {"role": "tuned", "selection_seed": 0}},
        {"method": "direction_velocity", "tags": {"role": "default", "selection_seed": 1}},
    ]
    return data


def test_explicit_settings_with_tags(tmp_path):
    spec = parse_spec(_explicit_spec())
    settings = spec.settings()
    assert [dict(s.static)["method"] for s in settings] == ["basic", "direction_velocity", "direction_velocity"]
    assert settings[0].gains["d_s"] == 3.0 and settings[2].gains["d_s"] == 4.0  # the default
    assert {s.gains["k_rep"] for s in settings} == {5.0}  # [gains] k_rep = 5
    assert (settings[1].gains["gamma"], settings[1].gains["k"]) == (2.0, 0.25)
    assert spec.tag_names == ("role", "selection_seed")
    assert SweepSpec.from_json(spec.to_json()) == spec
    out = tmp_path / "explicit.parquet"
    run_sweep(spec, out, quiet=True)
    df, _ = read_sweep(out)
    names = pq.read_schema(next(out.glob("part-*.parquet"))).names
    assert names.index("role") == names.index("selection_seed") - 1 < names.index("family")
    table = df.groupby("setting")[["method", "d_s", "gamma", "role", "selection_seed"]].first()
    assert table.to_dict("list") == {"method": ["basic", "direction_velocity", "direction_velocity"],
                                     "d_s": [3.0, 4.0, 4.0], "gamma": [1.0, 2.0, 1.0],
                                     "role": ["tuned", "tuned", "default"], "selection_seed": [0, 0, 1]}


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(grid={"gamma": [1.0]}), "setting: [[setting]] tables list the settings themselves"),
    (lambda d: d["setting"][1].update(k_rep=1.0), "setting[1].k_rep is also set in [gains]"),
    (lambda d: d["setting"][0].update(gama=1.0), "setting[0].gama is not a known key"),
    (lambda d: d["setting"][0].update(gamma=-1.0), "setting[0].gamma = -1.0 is out of range"),
    (lambda d: d["setting"][2]["tags"].pop("role"), "setting[2].tags has selection_seed; every setting needs"),
    (lambda d: d["setting"][2]["tags"].update(role=3), "setting[2].tags.role = 3: setting[0] gives it as text"),
    (lambda d: d["setting"][0]["tags"].update(success="x"), "setting[0].tags.success: a tag is"),
    (lambda d: d["setting"][0]["tags"].update(role=1.5), "setting[0].tags.role = 1.5 must be text or an integer"),
])
def test_explicit_settings_are_validated(change, message):
    data = _explicit_spec()
    change(data)
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_spec(data)


def test_a_variant_is_a_family_of_its_own_name(tmp_path):
    from jaxapf.simulate import simulate_runs

    data = copy.deepcopy(TINY)
    data["scenario"]["families"] = ["crossing", "crossing_fast"]
    data["scenario"]["params"] = {"crossing": {"max_obstacles": 5},
                                  "crossing_fast": {"family": "crossing", "max_obstacles": 5, "speed": [2.0, 3.0]}}
    spec = parse_spec(data)
    assert spec.family_params("crossing_fast").speed == (2.0, 3.0)
    assert SweepSpec.from_json(spec.to_json()) == spec
    out = tmp_path / "variants.parquet"
    run_sweep(spec, out, quiet=True)
    df, meta = read_sweep(out)
    assert set(df["family"]) == {"crossing", "crossing_fast"} and set(df["kind"]) == {"crossing"}
    # same keys, other speeds: the variant's fields differ from the family's
    a = df[(df.family == "crossing") & (df.setting == 3)]["min_clearance"].to_numpy()
    b = df[(df.family == "crossing_fast") & (df.setting == 3)]["min_clearance"].to_numpy()
    assert not np.array_equal(a, b)
    row = df[(df.family == "crossing_fast") & (df.setting == 3)].iloc[1]
    cfg = row_config(meta, row.to_dict())
    assert (cfg.family, cfg.label, cfg.overrides) == ("crossing", "crossing_fast",
                                                      {"max_obstacles": 5, "speed": [2.0, 3.0]})
    _, runs, _ = simulate_runs(cfg.family, cfg.seed, cfg.field, [cfg.sim.planner.method], cfg.gains, cfg.sim,
                               cfg.mpc, cfg.overrides)
    assert runs[0].metrics["steps"] == row["steps"]
    np.testing.assert_allclose(runs[0].metrics["min_clearance"], row["min_clearance"], rtol=1e-4)


def test_row_config_resimulates_a_row(reference):
    from jaxapf.simulate import simulate_runs

    _, df, meta = reference
    row = df[(df.setting == 3) & (df.family == "trap")].iloc[2]
    cfg = row_config(meta, row.to_dict())
    assert (cfg.family, cfg.field, cfg.seed) == ("trap", int(row["field"]), 1)
    assert cfg.gains == Gains(gamma=1.0, k_rep=5.0) and cfg.overrides == {"distance": [4.0, 6.0]}
    assert cfg.sim == SimConfig.from_flat(method="direction_velocity", t_max=2.0)
    assert cfg.mpc == MPCConfig(horizon=3, iters=3)
    _, runs, _ = simulate_runs(cfg.family, cfg.seed, cfg.field, [cfg.sim.planner.method], cfg.gains, cfg.sim, cfg.mpc,
                               cfg.overrides)
    for m in ("success", "collision", "steps"):
        assert runs[0].metrics[m] == row[m]
    np.testing.assert_allclose(runs[0].metrics["path_length"], row["path_length"], rtol=1e-4)


def test_read_sweep_refuses_what_is_not_a_sweep(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        read_sweep(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="holds no Parquet part file"):
        read_sweep(tmp_path / "empty")
    pd.DataFrame({"a": [1]}).to_parquet(tmp_path / "plain.parquet")
    with pytest.raises(ConfigError, match="is not the output of jaxapf sweep"):
        read_sweep(tmp_path / "plain.parquet")


# --------------------------------------------------------------------------------------------
# determinism, resume, refusal
# --------------------------------------------------------------------------------------------


def test_chunk_size_does_not_change_a_number(reference, tmp_path):
    _, ref, _ = reference
    out = tmp_path / "small-chunks.parquet"
    run_sweep(_spec(), out, chunk_fields=2, quiet=True)
    assert len(list(out.iterdir())) == 2 * 2 * 3  # variants × families × ceil(6 / 2)
    df, _ = read_sweep(out)
    pd.testing.assert_frame_equal(df, ref)


class _Crash(Exception):
    pass


def test_resume_after_a_crash_loses_and_doubles_nothing(reference, tmp_path):
    _, ref, _ = reference
    out = tmp_path / "crash.parquet"
    written = []

    def crash_after_three(chunk):
        written.append(chunk)
        if len(written) == 3:
            raise _Crash

    with pytest.raises(_Crash):
        run_sweep(_spec(), out, chunk_fields=2, quiet=True, after_part=crash_after_three)
    assert sorted(p.name for p in out.iterdir()) == sorted(c.name for c in written)
    (out / ".part-v000-trap-f00000002-00000004.parquet.tmp-99999").write_bytes(b"half a file")  # a killed write
    # resume with another chunk size: the remaining fields are re-cut, finished parts kept
    result = run_sweep(_spec(), out, chunk_fields=4, quiet=True)
    assert result.skipped == 3 * 2 * 2 and result.episodes == ROWS - result.skipped
    assert not any(p.name.startswith(".") for p in out.iterdir())
    df, meta = read_sweep(out)
    assert meta["complete"]
    pd.testing.assert_frame_equal(df, ref)
    # a finished sweep rerun does nothing
    assert run_sweep(_spec(), out, quiet=True).episodes == 0


def test_changed_spec_is_refused_unless_overwrite(reference, tmp_path):
    out = tmp_path / "copy.parquet"
    shutil.copytree(reference[0], out)
    changed = _spec(**{"scenario.seed": 2})
    with pytest.raises(ConfigError, match="holds a different sweep .*spec_hash.*--overwrite"):
        run_sweep(changed, out, quiet=True)
    run_sweep(changed, out, overwrite=True, quiet=True)
    df, meta = read_sweep(out)
    assert meta["spec_hash"] == changed.hash and len(df) == ROWS and set(df["seed"]) == {2}
    assert not np.array_equal(df["path_length"], reference[1]["path_length"])
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="holds entries that are not sweep parts"):
        run_sweep(changed, out, overwrite=True, quiet=True)


def test_identical_settings_run_once_and_give_the_rows_of_separate_runs(reference, tmp_path):
    """``basic`` ignores γ: its two γ settings are one simulation, repeated, and said so."""
    _, ref, _ = reference
    plan = plan_sweep(_spec())
    assert plan.duplicates == 1 and plan.variants[0].simulated == (0,) and plan.variants[0].inverse == (0, 0)
    assert plan.variants[1].simulated == (0, 1)  # direction_velocity reads γ
    metrics = list(METRICS.names())
    basic = ref[ref["method"] == "basic"]
    for gamma in (0.0, 1.0):
        alone = run_sweep(_spec(**{"grid.method": ["basic"], "grid.gamma": [gamma]}), tmp_path / f"g{gamma}",
                          quiet=True)
        assert alone.duplicates == 0
        df, _ = read_sweep(tmp_path / f"g{gamma}")
        mine = basic[basic["gamma"] == gamma].sort_values(["family", "field"])
        np.testing.assert_allclose(mine[metrics].to_numpy(float), df.sort_values(["family", "field"])[metrics]
                                   .to_numpy(float), rtol=1e-6)
    result = run_sweep(_spec(), tmp_path / "again", quiet=True)
    assert result.duplicates == 1 and "1 setting(s) repeat an earlier one" in result.summary("tiny")
    assert "1 repeat an earlier setting" in describe_plan(plan)


def test_dry_run_prints_the_plan(reference, tmp_path, capsys):
    spec_path = _toml(tmp_path / "tiny.toml", TINY)
    rc = main(["sweep", str(spec_path), "--dry-run", "--no-cache", "--devices", "1",
               "--out", str(tmp_path / "none.parquet"), "--chunk-fields", "4"])
    text = capsys.readouterr().out
    assert rc == 0 and not (tmp_path / "none.parquet").exists()
    for line in ("settings:          4, in 2 static variant(s)", f"episodes:          {ROWS}",
                 "compiled variants: 2 distinct (SimConfig, MPCConfig)", "chunks:            8 to run",
                 "time estimate:", "cost model", "memory estimate:",
                 "are padding: the spec's 6 fields", "(padded to 16 fields)"):
        assert line in text, line
    assert "--chunk-fields 16" not in text  # more chunk fields than the spec has would not help
    # against a finished output: nothing left to run
    rc = main(["sweep", str(spec_path), "--dry-run", "--no-cache", "--devices", "1", "--out", str(reference[0])])
    assert rc == 0 and f"({ROWS} already in the output, 0 to run)" in capsys.readouterr().out


def test_dry_run_counts_the_sequential_control_steps_by_hand():
    """1,024 episodes of 20 steps in one chunk at width 512: the streaming engine flies them on 256 slots
    (a quarter of the queue), four one after the other on each slot: 80 steps; two such chunks, 160."""
    spec = parse_spec({"name": "steps", "scenario": {"families": ["trap"], "fields": 2048, "seed": 0},
                       "sim": {"t_max": 2.0}})
    plan = plan_sweep(spec, chunk_fields=1024, devices=1, width=512)
    assert [plan.blocks[(0, "trap")].settings, plan.blocks[(0, "trap")].per_device, len(plan.chunks)] == [1, 1024, 2]
    assert plan.blocks[(0, "trap")].sim.episode.steps == 20
    assert plan.control_steps() == 2 * 4 * 20
    assert "up to 160 one after another on each device" in describe_plan(plan)


def test_plan_gives_every_device_a_whole_vmapped_batch():
    plan = plan_sweep(_spec(), chunk_fields=2, devices=4, width=32)
    block = plan.blocks[(0, "trap")]
    assert block.fields == 2 and block.padded == 4 * block.per_device
    assert block.per_device * block.settings == 32  # one whole vmapped batch on every device
    crossing = [(c.start, c.stop) for c in plan.chunks if (c.variant, c.family) == (1, "crossing")]
    assert crossing == [(0, 2), (2, 4), (4, 6)]
    # more fields than one batch: no padding to whole batches (evaluate pads its last batch)
    wide = plan_sweep(_spec(**{"scenario.fields": 40}), chunk_fields=40, devices=1, width=32).blocks[(0, "trap")]
    assert wide.per_device == wide.padded == 40


def test_padding_note_advises_no_more_chunk_fields_than_the_spec_has():
    few = plan_sweep(_spec(**{"scenario.fields": 2}), devices=1, width=32)
    note = few.padding_note()
    assert note is not None and "--chunk-fields" not in note, note
    assert "the spec's 2 fields" in note and "less than one vmapped batch of 32 episodes" in note, note
    odd = plan_sweep(_spec(**{"scenario.fields": 40}), chunk_fields=3, devices=1, width=32).padding_note()
    assert odd is not None and "--chunk-fields" in odd, odd


def test_long_episodes_narrow_their_vmap_width_to_fit_the_default_budget():
    """Only the (variant, family) whose episodes are long runs narrower; the others keep the width."""
    data = {"name": "long", "scenario": {"families": ["clutter", "trap"], "fields": 4096,
                                         "params": {"clutter": {"max_obstacles": 16}}},
            "grid": {"t_max": [30.0, 300.0]}}
    plan = plan_sweep(parse_spec(data), devices=1)
    assert plan.width == default_width()
    widths = {key: b.width for key, b in plan.blocks.items()}
    assert widths[(0, "clutter")] == widths[(0, "trap")] == plan.width  # 300 steps fit
    long = plan.blocks[(1, "clutter")]
    assert working_set_bytes(long.width, 3000, 16, 4) <= WIDTH_BUDGET < working_set_bytes(2 * long.width, 3000, 16, 4)
    assert widths[(1, "trap")] > long.width  # 5 obstacle slots: a wider batch fits
    assert plan.peak_bytes <= DEFAULT_MEMORY_BUDGET


# --------------------------------------------------------------------------------------------
# devices
# --------------------------------------------------------------------------------------------

_SHARDED = textwrap.dedent("""
    import json, sys
    from jaxapf.sweep import parse_spec, run_sweep
    import jax
    assert jax.local_device_count() == 4, jax.devices()
    run_sweep(parse_spec(json.loads(sys.argv[1])), sys.argv[2], quiet=True, chunk_fields=5)
""")


@pytest.mark.slow
def test_four_devices_give_the_rows_of_one(tmp_path):
    data = copy.deepcopy(TINY)
    data["grid"] = {"gamma": [0.0, 1.0]}  # one static variant: one program per device
    data["scenario"]["fields"] = 11
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"}
    sharded = tmp_path / "four.parquet"
    proc = subprocess.Popen([sys.executable, "-c", _SHARDED, json.dumps(data), str(sharded)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    single = tmp_path / "one.parquet"
    run_sweep(parse_spec(data), single, quiet=True)
    log, _ = proc.communicate(timeout=240)
    assert proc.returncode == 0, log
    a, meta_a = read_sweep(single)
    b, meta_b = read_sweep(sharded)
    assert meta_b["versions"]["device_count"] == "4" and meta_a["versions"]["device_count"] == "1"
    # four devices shard the batch into other vmap widths, which XLA may round apart
    assert_same_episodes(a, b, SimConfig().episode.dt)  # TINY flies the default dt


def test_a_bad_shard_is_one_line(tmp_path, capsys):
    spec = _toml(tmp_path / "tiny.toml", TINY)
    for bad in ("2/2", "1", "-1/4", "a/b", "0/0"):
        assert main(["sweep", str(spec), f"--shard={bad}", "--no-cache", "--dry-run"]) == 2
        assert "--shard = " in capsys.readouterr().err
    assert main(["sweep", str(spec), "--shard", "0/2", "--devices", "2", "--no-cache", "--out",
                 str(tmp_path / "o")]) == 2
    assert "a shard runs on one device" in capsys.readouterr().err


def test_a_grid_over_an_mpc_weight_traces_the_weights(tmp_path):
    """Naming an MPC weight scale in the grid flies the weights from the gains (``mpc_weights = "gains"``)
    and gives it a column; the two settings fly different episodes."""
    spec = _spec(**{"grid.mpc_pos": [0.2, 5.0], "grid.method": ["basic"], "grid.gamma": [1.0]})
    assert all(spec.configs(s.static, "trap")[0].planner.mpc_weights == "gains" for s in spec.settings())
    result = run_sweep(spec, tmp_path / "out", quiet=True)
    rows, _ = read_sweep(result.out)
    assert "mpc_pos" in rows.columns and sorted(rows["mpc_pos"].unique()) == [0.2, 5.0]
    by_setting = rows.groupby("mpc_pos")["final_distance"].mean()
    assert abs(by_setting[0.2] - by_setting[5.0]) > 1e-3


def test_mpc_scales_of_one_leave_the_weights_compiled_in():
    """A gains file that lists every gain at its default (what ``jaxapf tune`` writes) sets the MPC's
    scales to 1: the weights stay static; a scale set to another value switches them to the gains."""
    from jaxapf.control import scales_set

    assert scales_set({"mpc_pos": 1.0, "k_rep": 3.0, "mpc_input": [1.0, 1.0]}) == ()
    assert scales_set({"mpc_pos": [1.0, 2.0], "mpc_speed": 0.5}) == ("mpc_pos", "mpc_speed")
    unit = _spec(**{"gains.mpc_pos": 1.0})
    assert all(unit.configs(s.static, "trap")[0].planner.mpc_weights == "static" for s in unit.settings())
    scaled = _spec(**{"gains.mpc_pos": 2.0})
    assert all(scaled.configs(s.static, "trap")[0].planner.mpc_weights == "gains" for s in scaled.settings())


def test_a_spec_expands_its_settings_once(monkeypatch):
    """Every part written asks for the gain columns, and each asks for the settings: a spec (frozen)
    expands them once, so a 2,000-sample ``[random]`` costs its expansion once per run, not per part."""
    from jaxapf.sweep.spec import SweepSpec

    calls = []
    real = SweepSpec.random_samples
    monkeypatch.setattr(SweepSpec, "random_samples", lambda self: calls.append(1) or real(self))
    spec = parse_spec({"name": "r", "scenario": {"families": ["trap"], "fields": 2},
                       "random": {"n": 50, "seed": 0, "k_rep": [1.0, 20.0]}})
    calls.clear()
    fresh = dataclasses.replace(spec)  # a new spec object: nothing expanded yet
    for _ in range(5):
        fresh.gain_columns()
        assert len(fresh.settings()) == 50
    assert len(calls) == 1
    first = fresh.settings()
    first.pop()  # the caller's list is its own
    assert len(fresh.settings()) == 50 and fresh.settings() == spec.settings()


def test_a_plan_resumed_is_the_plan_made_with_what_is_done():
    """``jaxapf sweep`` plans once and resumes that plan with the finished chunks it finds: the same chunks
    as planning again with them (holes, a chunk cut short, a finished family)."""
    from jaxapf.sweep.plan import Chunk, plan_sweep

    spec = _spec(**{"scenario.fields": 40})
    whole = plan_sweep(spec, chunk_fields=8, devices=1, width=32)
    done = (Chunk(0, "trap", 0, 8), Chunk(0, "trap", 16, 20), *[c for c in whole.chunks if c.family != "trap"])
    assert whole.resumed(done) == plan_sweep(spec, done=done, chunk_fields=8, devices=1, width=32)
    assert whole.resumed(done).chunks and whole.resumed(()) == whole


def test_a_run_expands_the_settings_once_and_writes_every_part_from_the_plan(tmp_path, monkeypatch):
    """The plan carries the expanded settings, the gain columns and the parts' metadata: once it is made,
    auditing the output and writing every part never asks the spec to expand its settings again, nor
    plans a second time."""
    import jaxapf.sweep.run as run

    calls = {"plan": 0}
    planned = run.plan_sweep

    def plan_once(*args, **kwargs):
        calls["plan"] += 1
        plan = planned(*args, **kwargs)
        for name in ("settings", "gain_columns"):  # from here on, an expansion is an error
            monkeypatch.setattr(SweepSpec, name, lambda self, name=name: pytest.fail(f"{name}() after planning"))
        return plan

    monkeypatch.setattr(run, "plan_sweep", plan_once)
    out = tmp_path / "once.parquet"
    result = run_sweep(_spec(), out, chunk_fields=3, quiet=True)
    assert calls["plan"] == 1 and result.parts == len(list(out.glob("part-*.parquet"))) == 8
    (out / sorted(p.name for p in out.glob("part-*.parquet"))[0]).unlink()
    monkeypatch.undo()
    monkeypatch.setattr(run, "plan_sweep", plan_once)
    calls["plan"] = 0
    again = run_sweep(_spec(), out, chunk_fields=3, quiet=True)  # a resume audits against the same plan
    assert calls["plan"] == 1 and again.parts == 1 and again.skipped == ROWS - again.episodes

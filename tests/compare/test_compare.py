"""``jaxapf compare``: the tuned comparison protocol at tiny size, and its parts against independent
computations (the selection's argmax recomputed with :func:`jaxapf.evaluate`, the budget arithmetic
by hand)."""

from __future__ import annotations

import copy
import dataclasses
import json
import re

import numpy as np
import pandas as pd
import pytest

from jaxapf import evaluate, stats
from jaxapf.cli import main
from jaxapf.compare import parse_compare_spec, run_compare_spec
from jaxapf.compare.select import gradient_steps, grid_candidates, random_candidates
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.gains import Gains
from jaxapf.scenarios import family_params, make_scenarios
from jaxapf.sweep import read_sweep
from jaxapf.tune.spec import split_count
from jaxapf.tune.train import stack_gains
from jaxapf.validation import ConfigError

pytestmark = pytest.mark.slow  # module fixtures train and compare for tens of seconds

SHORT = {"distance": [5.0, 6.0]}
TINY = {
    "name": "tiny",
    "methods": ["basic", "direction_velocity"],
    "selection": {"families": ["trap", "crossing"], "seeds": [1, 2, 3], "budget": 24, "candidates": 4},
    "test": {"families": ["trap", "head_on"], "fields": 6, "seed": 10},
    "sim": {"t_max": 8.0, "horizon": 4, "iters": 4},
    "scenario": {"params": {"trap": SHORT, "crossing": SHORT | {"max_obstacles": 5}, "head_on": SHORT}},
}


def _spec(**changes):
    """TINY with ``changes`` at dotted keys (``None`` removes a key)."""
    data = copy.deepcopy(TINY)
    for dotted, value in changes.items():
        *path, key = dotted.split(".")
        table = data
        for p in path:
            table = table.setdefault(p, {})
        if value is None:
            table.pop(key, None)
        else:
            table[key] = value
    return parse_compare_spec(data)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("compare") / "tiny"
    spec = _spec()
    summary = run_compare_spec(spec, "(test)", out, quiet=True, resamples=200)
    return spec, out, summary


def test_every_method_gets_the_same_budget_for_every_seed(run):
    spec, out, _ = run
    table = pd.read_csv(out / "selection.csv")
    assert len(table) == len(spec.methods) * len(spec.selection.seeds)
    assert set(table["episodes"]) == {24} and set(table["budget"]) == {24}
    assert set(table["candidates"]) == {4} and set(table["fields_per_candidate"]) == {6}


def test_the_test_flies_every_selection_on_the_same_held_out_fields(run):
    spec, out, _ = run
    df, meta = read_sweep(out / "test.parquet")
    assert meta["spec"]["scenario"]["seed"] == 10
    assert len(df) == 2 * 4 * 2 * 6  # methods × (default + 3 seeds) × families × fields
    assert set(df["selection"]) == {"default", "seed1", "seed2", "seed3"}
    assert (df.groupby(["family", "field"])["setting"].nunique() == 8).all()  # paired on every field
    selections = {(s["method"], s["seed"]): s["gains"] for s in
                  (json.loads(p.read_text())["selection"] for p in (out / "selection").glob("*.json"))}
    for (method, seed), gains in selections.items():
        rows = df[(df["method"] == method) & (df["selection"] == f"seed{seed}")]
        for g in spec.method_gains(method):
            assert set(rows[g]) == {gains[g]}
    defaults = df[df["selection"] == "default"]
    for g in spec.selection.gains:  # the searched gains, at their declared defaults
        assert set(defaults[g]) == {Gains().floats()[g]}


def test_report_pairs_each_setting_with_the_baseline_of_its_selection(run):
    _, out, _ = run
    comparisons = pd.read_csv(out / "report" / "comparisons.csv")
    summary = pd.read_csv(out / "report" / "summary.csv")
    selection = summary.groupby("setting")["selection"].first()
    method = summary.groupby("setting")["method"].first()
    for s, b in comparisons[["setting", "baseline"]].drop_duplicates().itertuples(index=False):
        assert method[s] == "direction_velocity" and method[b] == "basic"
        assert selection[s] == selection[b]
    md = (out / "compare.md").read_text()
    for heading in ("## Selection: budget and outcome", "## Selected gains", "spread", "## Against the baseline"):
        assert heading in md


def test_selection_is_the_argmax_of_success_recomputed_independently(run):
    spec, out, _ = run
    # the candidates of basic, seed 2, flown again with jaxapf.evaluate on the same training fields
    candidates = random_candidates(spec, "basic", 2)
    fields = [make_scenarios(2, family_params(f, **spec.params[f]), np.arange(c))
              for f, c in zip(spec.selection.families, split_count(6, 2))]
    sim, mpc = SimConfig.from_flat(method="basic", t_max=8.0), MPCConfig(horizon=4, iters=4)
    success = sum(np.asarray(evaluate(f, stack_gains(candidates), sim, mpc)["success"]).sum(axis=1) for f in fields)
    chosen = json.loads((out / "selection" / "basic-seed2.json").read_text())["selection"]
    best = [i for i, c in enumerate(candidates) if success[i] == success.max()]
    assert any(candidates[i].floats() == chosen["gains"] for i in best)
    assert chosen["selection_success"] == pytest.approx(success.max() / 6)


def test_a_rerun_reuses_what_is_finished_and_a_changed_spec_is_refused(run):
    spec, out, summary = run
    again = run_compare_spec(spec, "(test)", out, quiet=True, resamples=200)
    assert again["selections"] == summary["selections"]  # read back, seconds included
    with pytest.raises(ConfigError, match="holds a comparison of another spec"):
        run_compare_spec(_spec(**{"selection.budget": 32}), "(test)", out, quiet=True, resamples=200)


def test_random_candidates_share_draws_across_methods_and_start_at_the_defaults():
    spec = _spec(**{"selection.candidates": 16})
    basic, dv = random_candidates(spec, "basic", 5), random_candidates(spec, "direction_velocity", 5)
    assert basic[0] == dv[0] == Gains() and len(basic) == 16
    for a, b in zip(basic, dv):
        assert all(getattr(a, g) == getattr(b, g) for g in ("k_rep", "d_s", "k_att", "eta"))
        assert (a.gamma, a.k) == (1.0, 0.5)  # basic reads neither: they stay at their defaults
    ranges = dict(spec.selection.ranges)
    for c in dv[1:]:
        for g, r in ranges.items():
            assert r.low <= getattr(c, g) <= r.high
    assert random_candidates(spec, "basic", 6)[1] != basic[1]


def test_grid_candidates_are_the_product_over_the_gains_a_method_reads():
    spec = _spec(**{"selection.search": "grid", "selection.candidates": None,
                    "selection.grid": {"k_rep": [5.0, 20.0], "gamma": [0.5, 2.0, 4.0]}})
    assert len(grid_candidates(spec, "basic")) == 2
    assert len(grid_candidates(spec, "direction_velocity")) == 6


@pytest.mark.parametrize("budget, per_step, val, every, steps", [
    (24, 4, 4, 2, 3),    # 3·4 + (1 + 2)·4 = 24
    (23, 4, 4, 2, 2),    # 2·4 + (1 + 1)·4 = 16 (3 steps would need 24)
    (100, 16, 8, 10, 5),  # 5·16 + 2·8 = 96
    (10, 16, 8, 10, 0),
])
def test_gradient_steps_fill_the_budget(budget, per_step, val, every, steps):
    assert gradient_steps(budget, per_step, val, every) == steps


@pytest.mark.parametrize("change, message", [
    ({"selection.seeds": [1, 2]}, "selection.seeds = [1, 2] must list at least 3 distinct seeds"),
    ({"selection.seeds": [1, 1, 2]}, "must list at least 3 distinct seeds"),
    ({"test.seed": 2}, "test.seed = 2 is also a selection seed"),
    ({"methods": ["basic"]}, "must list at least two planners"),
    ({"methods": ["basic", "magic"]}, "methods[1] = 'magic' is not a registered planner"),
    ({"methods": ["basic", "basic+magic"]}, "methods[1] = 'basic+magic': 'magic' is not a registered safety filter"),
    ({"methods": ["basic", "basic+cbf"], "sim.filter": "cbf"}, "methods[1] = 'basic+cbf' names a filter and [sim] "
                                                                "sets filter = 'cbf'"),
    ({"methods": ["basic", "basic"]}, "lists a method twice"),
    ({"baseline": "direction"}, "baseline = 'direction' is not allowed"),
    ({"selection.budget": 0}, "selection.budget = 0 is out of range"),
    ({"selection.search": "bayes"}, "selection.search = 'bayes' is not allowed"),
    ({"selection.grid": {"k_rep": [1.0]}}, "selection.grid is for search = \"grid\""),
    ({"selection.ranges": {"k_rep": [5.0, 1.0]}}, "selection.ranges.k_rep = [5.0, 1.0] is not a range"),
    ({"selection.gains": ["d_min"]}, "selection.gains[0] = 'd_min' is not a tunable gain"),
    ({"selection.gains": ["k_rep", "mpc_pos"], "sim.mpc_weights": "static"},
     "sim.mpc_weights = 'static' compiles the MPC's weights in, but the spec sets mpc_pos"),
    ({"sim.method": "basic"}, "sim.method is not a known key"),
    ({"test.families": ["forest"]}, "test.families[0] = 'forest' is not a family or variant"),
    ({"scenario.params.clutter": {"density": 1.0}}, "scenario.params.clutter is not one of selection.families"),
    ({"selection.budget": 10**9}, "selection.budget = 1000000000 is out of range; allowed: an integer >= 1 and "
                                  "<= 4194304"),
    ({"selection.candidates": 10**9}, "selection.candidates = 1000000000 is out of range"),
    ({"test.fields": 5 * 10**9}, "test.fields = 5000000000 is out of range"),
    ({"methods": ["basic", "learned_weight"]}, "selection: learned_weight reads omega_params (1,217 numbers), which "
                                                "a random search cannot choose; give it selection.searches."
                                                "learned_weight = \"gradient\""),
    ({"selection.searches": {"vortex": "gradient"}}, "selection.searches.vortex is not a known key"),
    ({"selection.searches": {"basic": "bayes"}}, "selection.searches.basic = 'bayes' is not allowed"),
    ({"selection.cmaes": {"sigma": 0.1}}, "selection.cmaes is for a cmaes or sep_cmaes search"),
    ({"selection.searches": {"basic": "cmaes"}, "selection.cmaes": {"sigma": 0.0}},
     "selection.cmaes.sigma = 0.0 is out of range"),
    ({"selection.searches": {"basic": "cmaes"}, "selection.cmaes": {"lambda": 4}}, "selection.cmaes.lambda is not"),
    ({"selection.search": "grid", "selection.grid": {"k_rep": [5.0 + i for i in range(400)],
                                                     "d_s": [2.0 + i for i in range(400)]}},
     "selection.grid expands to 160,000 settings; at most 100,000 are allowed"),
])
def test_bad_specs_name_the_key(change, message):
    data = copy.deepcopy(TINY)
    with pytest.raises(ConfigError, match=re.escape(message)):
        for dotted, value in change.items():
            *path, key = dotted.split(".")
            table = data
            for p in path:
                table = table.setdefault(p, {})
            table[key] = value
        parse_compare_spec(data)


def test_cli_reports_a_bad_spec_in_one_line(tmp_path, capsys):
    spec = tmp_path / "bad.toml"
    spec.write_text('name = "x"\nmethods = ["basic", "direction"]\n[selection]\nfamilies = ["trap"]\n'
                    'seeds = [1, 2]\nbudget = 8\n[test]\nfamilies = ["trap"]\nfields = 2\n')
    assert main(["compare", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxapf compare: error: selection.seeds")


def test_a_method_with_a_safety_filter_is_its_own_contender():
    """``PLANNER+FILTER``: the filter's gains are searched for it alone, every test setting carries a
    ``filter`` column (``none`` for the others) and the report's baseline names planner and filter."""
    from jaxapf.compare.protocol import baseline_filter, rows_of, test_sweep_spec
    from jaxapf.compare.select import Selection, tune_spec

    spec = _spec(methods=["basic+cbf", "basic", "velocity_obstacle"])
    assert "cbf_p1" in spec.method_gains("basic+cbf") and "cbf_p1" not in spec.method_gains("basic")
    assert "vo_tau" in spec.method_gains("velocity_obstacle") and "vo_tau" not in spec.method_gains("basic")
    assert tune_spec(spec, "basic+cbf", 1).sim.planner.filter == "cbf"
    assert baseline_filter(spec) == "method=basic,filter=cbf"
    selections = [Selection(m, seed, "random", Gains().floats() | {"cbf_p1": 0.5 + seed}, 4, 6, 24, 24, 0.0, 0.0,
                            0.0, "defaults") for seed in (1, 2, 3) for m in spec.methods]
    test = test_sweep_spec(spec, selections)
    settings = test.settings()
    assert [(dict(s.static)["method"], dict(s.static)["filter"]) for s in settings[:3]] == [
        ("basic", "cbf"), ("basic", "none"), ("velocity_obstacle", "none")]
    by = {(dict(s.static)["method"], dict(s.static)["filter"], dict(s.tags)["selection"]): dict(s.gains)
          for s in settings}
    assert by[("basic", "cbf", "seed2")]["cbf_p1"] == 2.5
    assert by[("basic", "none", "seed2")].get("cbf_p1", 1.0) == 1.0  # not searched: its default
    table = pd.DataFrame({"method": ["basic", "basic", "velocity_obstacle"], "filter": ["cbf", "none", "none"]})
    assert list(rows_of(table, spec, "basic").index) == [1]
    assert list(rows_of(table, spec, "basic+cbf").index) == [0]


def test_a_default_on_its_bound_is_searched_at_random_and_refused_where_a_search_starts_from_it(tmp_path):
    """``cbf_brake``'s default, 0.5, is its upper bound, which no θ reaches: a random selection scores its
    candidates (the defaults first, 0.5 kept; before, every selection of a braking stack was refused), while a
    CMA-ES selection, which starts from the defaults, is refused in one line naming ``init.cbf_brake``."""
    from jaxapf.compare.select import random_candidates, select, tune_spec

    method = "basic+braking_cbf"
    spec = _spec(methods=["basic", method], **{"selection.gains": ["k_rep", "cbf_brake"]})
    assert random_candidates(spec, method, 1)[0].cbf_brake == 0.5
    chosen = select(spec, method, 1, tmp_path / "selection")
    assert chosen.episodes == 24 and 0.05 <= chosen.gains["cbf_brake"] <= 0.5
    started = _spec(methods=["basic", method], **{"selection.gains": ["k_rep", "cbf_brake"],
                                         "selection.searches": {method: "cmaes"}})
    with pytest.raises(ConfigError, match=r"init\.cbf_brake = 0\.5 must lie strictly inside \(0\.05, 0\.5\)"):
        tune_spec(started, method, 1)


def test_fixed_gains_are_the_world_every_candidate_and_the_test_fly_in():
    """``[gains]`` fixes gains no selection searches (a wind to select and test in): every candidate and
    the tune spec start from them, the test sweep flies them, and a searched gain cannot be fixed too."""
    from jaxapf.compare.protocol import test_sweep_spec
    from jaxapf.compare.select import Selection, spec_digest, tune_spec

    wind = {"wind_speed": 4.0, "wind_heading": 90.0}
    spec = _spec(**{"gains": wind, "sim.disturbance": "wind"})
    assert dict(spec.gains) == wind and spec_digest(spec) != spec_digest(_spec(**{"sim.disturbance": "wind"}))
    for method in spec.methods:
        for candidate in random_candidates(spec, method, 1) + grid_candidates(spec, method):
            assert candidate["wind_speed"] == 4.0 and candidate["wind_heading"] == 90.0
        assert tune_spec(spec, method, 1).init["wind_speed"] == 4.0
    chosen = [Selection(m, s, "random", dict(random_candidates(spec, m, s)[1].floats()), 4, 6, 24, 24, 0.0, 0.5, 1.0,
                        "candidate 1") for s in spec.selection.seeds for m in spec.methods]
    test = test_sweep_spec(spec, chosen)
    assert test.gains["wind_speed"] == 4.0 and "wind_speed" in test.gain_columns()
    with pytest.raises(ConfigError, match="gains.k_rep is also searched"):
        _spec(**{"gains": {"k_rep": 5.0}})
    with pytest.raises(ConfigError, match="gains.wind_sped is not a known key"):
        _spec(**{"gains": {"wind_sped": 5.0}})
    assert spec_digest(_spec()) == spec_digest(_spec(**{"gains": {}}))  # no [gains]: the digest it always had


def test_a_searched_mpc_weight_traces_the_mpcs_weights_in_selection_and_test():
    """Naming an MPC weight scale in ``selection.gains`` switches ``mpc_weights`` to ``gains`` (as sweep and
    tune specs do): the method searches it, its tune spec and the test sweep trace the weights."""
    from jaxapf.compare.protocol import test_sweep_spec
    from jaxapf.compare.select import Selection, tune_spec

    spec = _spec(**{"selection.gains": ["k_rep", "mpc_pos"]})
    assert spec.sim["mpc_weights"] == "gains" and spec.method_gains("basic") == ("k_rep", "mpc_pos")
    assert tune_spec(spec, "basic", 1).sim.planner.mpc_weights == "gains"
    chosen = [Selection(m, s, "random", dict(random_candidates(spec, m, s)[1].floats()), 4, 6, 24, 24, 0.0, 0.5, 1.0,
                        "candidate 1") for s in spec.selection.seeds for m in spec.methods]
    test = test_sweep_spec(spec, chosen)
    assert test.configs(test.settings()[0].static, "trap")[0].planner.mpc_weights == "gains"
    assert "mpc_weights" not in _spec().sim  # no scale named: the spec (and its digest) as before


def test_shards_of_a_comparison_give_the_one_process_selections_and_test_rows(run, tmp_path):
    """Four shards run twice in a shuffled order (as two passes of a job array): a shard whose
    selections are done waits for the others' before the test; then the command without --shard
    finds every selection and test part there and writes the report; selections and test rows are
    the one-process run's."""
    from jaxapf.sweep.output import part_files, part_record

    spec, reference, summary = run
    out = tmp_path / "sharded"
    first = {i: run_compare_spec(spec, "(test)", out, quiet=True, shard=(i, 4)) for i in (3, 1, 0, 2)}
    assert [first[i]["selections_missing"] for i in (3, 1, 0)] == [5, 3, 1] and "test" in first[2]
    assert all(first[i]["selections_done"] + first[i]["selections_missing"] == 6 for i in first)
    written = {p.name: p.stat().st_mtime_ns for p in part_files(out / "test.parquet")}
    second = {i: run_compare_spec(spec, "(test)", out, quiet=True, shard=(i, 4)) for i in (3, 1, 0, 2)}
    assert all("test" in r for r in second.values())
    # shard 2's test parts of the first pass are found, not written again (its time is no test on a loaded machine)
    after = {p.name: p.stat().st_mtime_ns for p in part_files(out / "test.parquet")}
    assert written and all(after[name] == t for name, t in written.items()) and len(after) > len(written)
    parts = part_files(out / "test.parquet")
    assert parts and all(part_record(p)["shard"][1] == 4 for p in parts)
    final = run_compare_spec(spec, "(test)", out, quiet=True, resamples=200)
    assert (out / "report" / "report.md").exists() and (out / "compare.md").exists()
    drop = lambda sels: [{k: v for k, v in s.items() if k != "seconds"} for s in sels]  # noqa: E731
    assert drop(final["selections"]) == drop(summary["selections"])
    pd.testing.assert_frame_equal(read_sweep(out / "test.parquet")[0], read_sweep(reference / "test.parquet")[0])


def test_the_selection_flies_the_families_own_episode_length():
    """Selection and test fly one episode length: the families' own where [sim] sets none (a scaled family's
    30 s; the selection once flew the default 60 s), [sim] t_max where it is set; specs of 60 s families keep
    their digest (their selections stay valid)."""
    from jaxapf.compare.select import selection_t_max, spec_digest, tune_spec

    scaled = {"family": "crossing", "scale": {"length": 0.25, "speed": 0.5}}
    data = copy.deepcopy(TINY)
    data["sim"].pop("t_max")
    data["selection"]["families"] = ["crossing_cf"]
    data["test"]["families"] = ["crossing_cf"]
    data["scenario"]["params"] = {"crossing_cf": scaled}
    spec = parse_compare_spec(data)
    assert selection_t_max(spec) == 30.0 == tune_spec(spec, "basic", 1).sim.episode.t_max
    data["sim"]["t_max"] = 12.0
    assert tune_spec(parse_compare_spec(data), "basic", 1).sim.episode.t_max == 12.0
    sixty = copy.deepcopy(TINY)
    sixty["sim"].pop("t_max")
    sixty["scenario"]["params"] = {}
    plain = parse_compare_spec(sixty)

    def before(spec):  # the digest as it was, without the selection's episode length
        import dataclasses
        import hashlib

        fields = {k: v for k, v in dataclasses.asdict(spec).items()
                  if k != "plugin_paths" and not (k == "gains" and not v)}
        fields["selection"] = {k: v for k, v in fields["selection"].items()
                               if k not in ("searches", "cmaes", "added")}  # (fields added later, empty here)
        return hashlib.sha256(json.dumps(fields, sort_keys=True, default=str).encode()).hexdigest()

    assert selection_t_max(plain) == 60.0 and spec_digest(plain) == before(plain)
    data["sim"].pop("t_max")
    assert spec_digest(parse_compare_spec(data)) != before(parse_compare_spec(data))


def test_each_method_by_its_own_search_under_the_same_budget(tmp_path):
    """``[selection.searches]``: ``basic`` by random search, ``direction_velocity`` by gradient training and the
    learned weight's 1,217 parameters by separable CMA-ES, each within the same budget for every seed; the held-out
    test flies each seed's network (a setting of its own), and compare.md says which search chose what."""
    spec = _spec(**{"methods": ["basic", "direction_velocity", "learned_weight"],
                    "selection.searches": {"direction_velocity": "gradient", "learned_weight": "sep_cmaes"},
                    "selection.gradient": {"fields_per_step": 4, "validation_fields": 4, "validate_every": 2},
                    "selection.cmaes": {"sigma": 0.1, "popsize": 4, "fields_per_candidate": 2},
                    "selection.gains": ["k_rep", "gamma", "omega_params"]})
    assert [spec.selection.search_of(m) for m in spec.methods] == ["random", "gradient", "sep_cmaes"]
    summary = run_compare_spec(spec, "(test)", tmp_path / "out", quiet=True, resamples=100)
    chosen = {(s["method"], s["seed"]): s for s in summary["selections"]}
    assert {s["search"] for s in summary["selections"]} == {"random", "gradient", "sep_cmaes"}
    assert all(s["episodes"] <= 24 for s in summary["selections"])
    assert chosen[("learned_weight", 1)]["episodes"] == 24 and chosen[("learned_weight", 1)]["candidates"] == 12
    nets = [np.asarray(chosen[("learned_weight", seed)]["gains"]["omega_params"]) for seed in (1, 2, 3)]
    assert all(n.shape == (1217,) for n in nets) and not np.array_equal(nets[0], nets[1])
    rows = read_sweep(tmp_path / "out" / "test.parquet")[0]
    learned = rows[rows["method"] == "learned_weight"]
    assert sorted(learned["selection"].unique()) == ["default", "seed1", "seed2", "seed3"]
    assert learned.groupby("selection")["setting"].nunique().eq(1).all()  # one setting per seed's network
    text = (tmp_path / "out" / "compare.md").read_text()
    assert "random search (gradient for direction_velocity; sep_cmaes for learned_weight)" in text
    assert "1,217 numbers (selection/learned_weight-seed2.json)" in text
    assert "omega_params" not in (tmp_path / "out" / "selection.csv").read_text()


def test_the_headline_gives_each_seeds_verdict_and_the_mean_over_the_seeds_with_its_interval(run):
    """compare.md's conclusion per rate: the seeds' verdicts, and the mean of the seeds' pooled differences with
    the t interval over the seeds, recomputed here from comparisons.csv."""
    _, out, _ = run
    comparisons = pd.read_csv(out / "report" / "comparisons.csv")
    summary = pd.read_csv(out / "report" / "summary.csv")
    tuned = summary[(summary["method"] == "direction_velocity") & (summary["selection"] != "default")]
    md = (out / "compare.md").read_text()
    for metric in ("success", "collision"):
        rows = comparisons[comparisons["setting"].isin(tuned["setting"]) & (comparisons["family"] == "all")
                           & (comparisons["metric"] == metric)]
        assert len(rows) == 3
        mean, lo, hi = stats.seed_interval(100 * rows["delta"].to_numpy())
        line = next(line for line in md.splitlines() if line.startswith(f"- direction_velocity vs basic, {metric}:"))
        assert f"mean over the seeds {mean:+.3g} [{lo:+.3g}, {hi:+.3g}] pp" in line
        for v in rows["verdict"]:
            assert v in line


def test_restored_selections_fly_the_same_test_without_selecting(run, tmp_path, monkeypatch):
    """A run given its table's selections (``restore``, as a study's ``--kept-selections``) selects nothing
    and flies the test rows of the run that selected them; a selection lacking a searched gain is refused."""
    import jaxapf.compare.select as select_module
    from jaxapf.compare.protocol import read_selections
    from jaxapf.compare.select import restore

    spec, reference, summary = run
    kept = read_selections(spec, reference / "selection.csv")
    out = tmp_path / "restored"
    restore(spec, kept, out / "selection")
    monkeypatch.setattr(select_module, "select_best", lambda *a, **k: pytest.fail("selected again"))
    run_compare_spec(spec, "(test)", out, quiet=True, resamples=200)
    pd.testing.assert_frame_equal(read_sweep(out / "test.parquet")[0], read_sweep(reference / "test.parquet")[0])
    lacking = dataclasses.replace(kept[0], gains={})
    with pytest.raises(ConfigError, match=f"{kept[0].method} seed {kept[0].seed} holds no "):
        restore(spec, [lacking], tmp_path / "refused")
    assert not (tmp_path / "refused").exists()

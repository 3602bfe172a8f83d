"""The scorecard (jaxapf.compare.scorecard) on a tiny frozen benchmark (tests/data/scorecard-tiny): the zoo scored
once and stored, a member scored again under another name reproducing its stored row bit for bit and equivalent
to it on every primary comparison, the leaderboard's numbers recomputed here, a stored part edited by hand, a zoo of
another digest and a folder flown by another engine or plugin refused, and a changed engine checked by flying a
sample again."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT

from jaxapf import stats
from jaxapf.cli import main
from jaxapf.compare.scorecard import DriftError, check_drift, load_scorecard, score_method, score_zoo
from jaxapf.validation import ConfigError

pytestmark = pytest.mark.slow  # the module fixture scores a zoo (tens of seconds)


@pytest.fixture(scope="module")
def zoo(tmp_path_factory):
    root = tmp_path_factory.mktemp("scorecard")
    folder = root / "card"
    shutil.copytree(ROOT / "tests" / "data" / "scorecard-tiny", folder)
    card = load_scorecard(folder=folder)
    score_zoo(card, root / "zoo", quiet=True)
    return card, root


@pytest.fixture(scope="module")
def again(zoo):
    card, root = zoo
    return score_method(card, "basic", root / "again", name="basic_again", quiet=True, resamples=200)


def test_a_member_scored_again_under_another_name_reproduces_its_stored_row(zoo, again):
    table = again.table.set_index("method")
    columns = ["rank", "episodes", "success", "success_lo", "success_hi", "collision", "collision_lo", "collision_hi",
               "clearance_median", "clearance_median_lo", "clearance_median_hi"]
    pd.testing.assert_series_equal(table.loc["basic", columns], table.loc["basic_again", columns], check_names=False,
                                   check_exact=True)  # equal success, one rank
    primary = again.comparisons[(again.comparisons["member"] == "basic")
                                & (again.comparisons["holm_family"] == "primary")]
    assert len(primary) == 2 and set(primary["verdict"]) == {"equivalent"}
    assert (primary["delta"] == 0).all()
    # the question is the whole card's: the primary family is the pooled group (here the one test family) alone
    assert set(again.comparisons.loc[again.comparisons["holm_family"] == "primary", "family"]) == {"crossing"}
    # what each selection realised stands beside its row: the same draws, the same episodes
    assert table.loc["basic_again", "selection_episodes"] == table.loc["basic", "selection_episodes"]
    assert table["selection_seconds"].gt(0).all()


def test_the_zoos_facts_are_its_leaderboard(zoo, again):
    """facts.json beside the card (what the README binds) holds the zoo's leaderboard, member by member, and
    each member's realised selection budget: the card's, in every seed."""
    card, root = zoo
    found = json.loads((card.folder / "facts.json").read_text())
    table = pd.read_csv(card.folder / "leaderboard.csv").set_index("method")
    assert found["digest"] == card.digest and found["members"] == len(card.spec.methods) == len(table)
    assert found["protocol"] == {"seeds": 3, "budget": 12, "candidates": 3, "families": 1, "test_fields": 128,
                                 "test_seed": 300}  # tests/data/scorecard-tiny/scorecard.toml
    for m in card.spec.methods:
        assert found["rank"][m] == table.loc[m, "rank"]
        for key in ("success", "success_lo", "success_hi", "collision", "clearance_median", "clearance_median_lo",
                    "clearance_median_hi"):
            assert found[key][m] == pytest.approx(table.loc[m, key], rel=1e-12, abs=1e-15)
        for f in card.spec.test.families:
            assert found["family_success"][f][m] == pytest.approx(table.loc[m, f"{f} success"], rel=1e-12)
            assert found["family_collision"][f][m] == pytest.approx(table.loc[m, f"{f} collision"], rel=1e-12)
        assert found["selection_episodes"][m] == card.spec.selection.budget
    sel = pd.read_csv(card.folder / "selection.csv")
    assert (sel["episodes"] == card.spec.selection.budget).all()
    assert found["selection_hours"] == pytest.approx(sel["seconds"].sum() / 3600, rel=1e-12)
    assert found["identical"] == [] and isinstance(found["selection_ties"], list)


def test_the_leaderboard_is_the_stored_episodes_recomputed(zoo, again):
    card, root = zoo
    from jaxapf.sweep import read_sweep

    stored, _ = read_sweep(card.folder / "episodes.parquet")
    for member, rows in stored.groupby("member"):
        per_seed = rows.groupby("selection")["success"].mean().to_numpy()
        mean, lo, hi = stats.seed_interval(per_seed)
        row = again.table.set_index("method").loc[member]
        assert (row["success"], row["success_lo"], row["success_hi"]) == pytest.approx((mean, lo, hi), rel=1e-12)
        medians = [np.median(c[np.isfinite(c)]) for _, c in rows.groupby("selection")["min_clearance"]]
        assert (row["clearance_median"], row["clearance_median_lo"], row["clearance_median_hi"]) == pytest.approx(
            stats.seed_interval(medians), rel=1e-12)
    # every member against the new method on the same (selection, field) pairs: the counts recomputed
    mine = stored[stored["member"] == "direction"].sort_values(["selection", "field"])
    base = stored[stored["member"] == "basic"].sort_values(["selection", "field"])
    row = again.comparisons.query("member == 'direction' and metric == 'success'").iloc[0]
    b = int(np.sum(base["success"].to_numpy() & ~mine["success"].to_numpy()))
    c = int(np.sum(~base["success"].to_numpy() & mine["success"].to_numpy()))
    assert row["discordant"] == f"b={b}, c={c}" and row["n_pairs"] == len(base)
    md = (root / "again" / "leaderboard.md").read_text()
    assert f"digest {card.digest}" in md and "basic_again (new)" in md and "at " in md
    assert "## Collision per family (%)" in md and "clearance shift m (exploratory)" in md


def test_a_stored_part_edited_by_hand_is_refused_in_one_line(zoo, tmp_path, capsys):
    card, _ = zoo
    folder = tmp_path / "card"
    shutil.copytree(card.folder, folder)
    import pyarrow.parquet as pq

    table = pq.read_table(folder / "episodes.parquet")
    flipped = table.set_column(table.schema.get_field_index("success"), "success", _flip(table.column("success")))
    pq.write_table(flipped, folder / "episodes.parquet")
    code = main(["scorecard", "--card", str(folder), "--method", "direction", "--name", "d2", "--out",
                 str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "stored episodes are refused" in err[0]


def _flip(column):
    import pyarrow as pa

    values = column.to_numpy(zero_copy_only=False)
    values = values.copy()
    values[0] = not values[0]
    return pa.array(values)


def test_a_changed_engine_flies_a_sample_again_and_pairs_only_if_it_agrees(zoo, tmp_path):
    card, _ = zoo
    folder = tmp_path / "card"
    shutil.copytree(card.folder, folder)
    kept = json.loads((folder / "identity.json").read_text())
    (folder / "identity.json").write_text(json.dumps(kept | {"jax": "0.0.elsewhere"}))
    moved = load_scorecard(folder=folder)
    said = check_drift(moved)
    assert said.startswith("engine changed (jax 0.0.elsewhere -> ") and "agree" in said
    assert check_drift(card) == "same engine"
    # the identity a scored folder's claim recorded serves (its plugins aside: the zoo flew none)
    from jaxapf.compare.scorecard import identity

    assert check_drift(card, engine=identity() | {"plugins": {"/x/mine.py": "0" * 64}}) == "same engine"
    said = check_drift(card, engine=identity() | {"jax": "0.0.elsewhere"})  # the engine as given
    assert said.startswith("engine changed (jax ") and "-> 0.0.elsewhere)" in said and "agree" in said
    # stored episodes another engine made differently: the sample disagrees, one line says how to rescore
    from jaxapf.sweep import read_sweep
    from jaxapf.sweep.output import write_rows

    df, meta = read_sweep(folder / "episodes.parquet")
    df.loc[df["member"] == card.spec.methods[0], "min_clearance"] += 0.01
    write_rows(folder, "episodes.parquet", df, meta, meta["metrics"])
    with pytest.raises(DriftError, match=f"--card {folder} --rescore"):
        check_drift(load_scorecard(folder=folder))


def test_a_name_of_the_zoo_and_a_missing_card_are_one_line(zoo, tmp_path, capsys):
    card, _ = zoo
    assert main(["scorecard", "--card", str(card.folder), "--method", "basic", "--out", str(tmp_path / "o")]) == 2
    assert "a zoo member of scorecard card has that name" in capsys.readouterr().err
    assert main(["scorecard", "--card", "v0"]) == 2
    assert "no scorecard at" in capsys.readouterr().err
    assert main(["scorecard", "--card", str(card.folder)]) == 0
    assert "| rank | method |" in capsys.readouterr().out


def test_a_card_whose_zoo_is_not_stored_is_one_line_naming_the_file(tmp_path, capsys):
    """A card without its stored zoo: showing its leaderboard, or reading its episodes, selections or identity,
    is one line naming the missing file and the command that scores the zoo."""
    from jaxapf.compare.scorecard import stored_episodes, stored_identity, stored_selections

    shutil.copy(ROOT / "tests" / "data" / "scorecard-tiny" / "scorecard.toml", tmp_path / "scorecard.toml")
    card = load_scorecard(folder=tmp_path)
    assert main(["scorecard", "--card", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no leaderboard.md beside the card" in err[0] and "--rescore" in err[0]
    for read, name in ((stored_episodes, "episodes.parquet"), (stored_identity, "identity.json"),
                       (stored_selections, "selection.csv")):
        with pytest.raises(ConfigError, match=f"no {re.escape(name)} beside the card .* --rescore"):
            read(card)


def test_the_tutorial_ranks_its_plugin_as_the_page_says(zoo, tmp_path, capsys):
    """docs/scorecard.md's path, run: its plugin block saved as the page names it, its command on the tiny card."""
    import subprocess
    import sys

    card, _ = zoo
    page = (ROOT / "docs" / "scorecard.md").read_text(encoding="utf-8")
    (plugin,) = re.findall(r"```python\n(.*?)```", page, flags=re.S)
    (command,) = re.findall(r"```bash\n(.*?)```", page, flags=re.S)
    (tmp_path / "ttc_weight.py").write_text(plugin, encoding="utf-8")
    args = command.split()[1:] + ["--card", str(card.folder), "--quiet", "--resamples", "200"]
    done = subprocess.run([sys.executable, "-m", "jaxapf", *args], cwd=tmp_path, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("ttc_weight: rank ")
    out = tmp_path / "runs" / "scorecard-card-ttc_weight"
    board = pd.read_csv(out / "leaderboard.csv")
    assert set(board["method"]) == {"basic", "direction", "ttc_weight"}
    comparisons = pd.read_csv(out / "comparisons.csv")
    assert set(comparisons["member"]) == {"basic", "direction"}
    chosen = json.loads((out / "selection" / "ttc_weight-seed1.json").read_text())["selection"]["gains"]
    assert "k_ttc" in chosen  # the plugin's gain is searched beside the field's


def test_the_pages_numbers_are_the_shipped_cards():
    """What docs/scorecard.md states of v1 and of the drift check is what the code holds."""
    from jaxapf.compare import scorecard

    page = (ROOT / "docs" / "scorecard.md").read_text(encoding="utf-8")
    spec = load_scorecard("v1").spec
    sel = spec.selection
    assert (f"random search of {sel.candidates} candidates on {sel.budget // sel.candidates} training fields, "
            f"{sel.budget:,} episode rollouts per method") in page.replace("\n", " ")
    assert f"{spec.test.fields} fields of each family, drawn from seed {spec.test.seed}" in page.replace("\n", " ")
    assert f"seeds {sel.seeds[0]}, {sel.seeds[1]} and {sel.seeds[2]}" in page
    assert f"({scorecard.SAMPLE_FIELDS} fields of each family" in page.replace("\n", " ")
    assert scorecard.AGREE == 1e-3 and "within 1 mm" in page.replace("\n", " ")
    assert len(sel.families) == 6 and "on six families" in page.replace("\n", " ")
    # the held-out seed is one no study's sweep or script draws the card's families from: study 16 alone draws
    # from it (SEED in a tuple too), its swarm families
    drawn = [p.name for p in (*(ROOT / "sweeps").glob("*.toml"), *(ROOT / "analysis").glob("*.py"))
             if re.search(rf"\bseed\s*=\s*{spec.test.seed}\b|SEED\s*=[\s\d,]*\b{spec.test.seed}\b",
                          p.read_text())]
    assert drawn == ["swarm_study.py"]
    swarms = re.search(r"^FAMILIES = \((.*)\)$", (ROOT / "analysis" / "swarm_study.py").read_text(), re.M)
    assert swarms and not set(re.findall(r'"(\w+)"', swarms.group(1))) & {*sel.families, *spec.test.families}
    assert "study 16 draws its swarms, another family, from it" in page.replace("\n", " ")


def test_the_searched_gains_are_frozen_and_a_new_methods_own_are_added():
    """v1 searches the gains its file lists, so a gain registered later moves no member's draws; a member scored
    again draws the zoo's candidates; a method reading a gain beyond them has it searched, after them."""
    from jaxapf.compare.select import random_candidates
    from jaxapf.validation import read_toml_file

    card = load_scorecard("v1")
    listed, _ = read_toml_file(card.folder / "scorecard.toml")
    assert card.spec.selection.gains == tuple(listed["selection"]["gains"])
    again = card.for_method("basic")
    assert again.selection.gains == card.spec.selection.gains
    for seed in card.spec.selection.seeds:
        assert random_candidates(again, "basic", seed) == random_candidates(card.spec, "basic", seed)
    tiny = load_scorecard(folder=ROOT / "tests" / "data" / "scorecard-tiny")
    assert "k_v" not in tiny.spec.selection.gains
    assert tiny.for_method("vortex").selection.gains == (*tiny.spec.selection.gains, "k_v")


def test_selection_ties_are_found_and_printed(zoo, again):
    """Two members of one seed at the same chosen candidate, selection success and surrogate loss are a tie
    (hand-made cases); the leaderboard names the stored zoo's ties, recomputed here from its selection.csv."""
    from jaxapf.compare.scorecard import selection_ties
    from jaxapf.compare.select import Selection

    def sel(method, seed, chosen, success, loss=1.0):
        return Selection(method, seed, "random", {}, 3, 4, 12, 12, 0.0, success, loss, chosen)

    made = [sel("a", 1, "candidate 2", 0.5), sel("b", 1, "candidate 2", 0.5), sel("c", 1, "candidate 2", 0.75),
            sel("d", 2, "candidate 2", 0.5), sel("e", 1, "candidate 1", 0.5), sel("f", 1, "candidate 2", 0.5, 1.5)]
    assert selection_ties(made) == [(1, "a", "b")]
    card, root = zoo
    table = pd.read_csv(card.folder / "selection.csv")
    expected = [f"seed {s}: {a.method} and {b.method}" for s, g in table.groupby("seed", sort=False)
                for i, (_, a) in enumerate(g.iterrows()) for _, b in list(g.iterrows())[i + 1:]
                if a.chosen == b.chosen and a.selection_success == b.selection_success
                and a.selection_loss == b.selection_loss]
    md = (root / "again" / "leaderboard.md").read_text()
    line = next(x for x in md.splitlines() if x.startswith("Selection ties"))
    assert line.endswith("none.") if not expected else all(e in line for e in expected)
    same = next(x for x in md.splitlines() if x.startswith("Identical episodes"))
    assert same.endswith(": basic and basic_again.")  # basic scored again flies basic's episodes bit for bit


def test_identical_members_are_those_with_equal_episodes():
    """Members whose read columns agree on every (selection, family, field) are identical, NaN clearances
    included; one differing clearance or one missing field separates them (hand-made)."""
    from jaxapf.compare.scorecard import identical_members

    def member(name, clearance, fields=(0, 1)):
        return pd.DataFrame({"member": name, "selection": "seed1", "family": "trap", "field": list(fields),
                             "success": [True, False][:len(fields)], "collision": [False, True][:len(fields)],
                             "stalled": False, "min_clearance": clearance[:len(fields)]})

    eps = pd.concat([member("a", [0.5, np.nan]), member("b", [0.5, np.nan]), member("c", [0.5, 0.25]),
                     member("d", [0.5], fields=(0,))], ignore_index=True)
    assert identical_members(eps) == [("a", "b")]
    assert identical_members(eps.iloc[::-1]) == [("b", "a")]


def test_a_zoo_of_another_digest_or_a_damaged_identity_is_refused_in_one_line(zoo, tmp_path, capsys):
    """Stored episodes scored under another protocol (the digest in identity.json is not the card's) are never
    paired: one line says so and how to rescore; a damaged identity.json is one line too."""
    card, _ = zoo
    folder = tmp_path / "card"
    shutil.copytree(card.folder, folder)
    kept = json.loads((folder / "identity.json").read_text())
    args = ["scorecard", "--card", str(folder), "--method", "direction", "--name", "d2", "--out", str(tmp_path / "o"),
            "--quiet"]
    for text, said in ((json.dumps(kept | {"digest": "0" * 64}), "scored under digest 000000000000…"),
                       ("{not json", "is damaged"), ("[1, 2]", "not a JSON object")):
        (folder / "identity.json").write_text(text)
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and said in err[0] and f"jaxapf scorecard --card {folder} --rescore" in err[0]


def test_an_output_folder_flown_by_another_engine_is_refused_not_mixed(zoo, again, tmp_path):
    """What a scored method's folder holds was flown by one engine (its identity.json): a second run there with
    another stops in one line before anything flies, instead of pairing old selections or test parts with new."""
    from jaxapf.validation import ConfigError

    card, root = zoo
    out = tmp_path / "again"
    shutil.copytree(root / "again", out)
    kept = json.loads((out / "identity.json").read_text())
    assert kept["source"] and isinstance(kept["plugins"], dict) and kept["processor"]
    (out / "identity.json").write_text(json.dumps(kept | {"source": "0" * 64}))
    with pytest.raises(ConfigError, match=re.escape("(source changed)")) as err:
        score_method(card, "basic", out, name="basic_again", quiet=True, resamples=200)
    assert "new --out" in str(err.value) and "\n" not in str(err.value)


def test_a_gain_of_the_scored_method_alone_draws_from_its_own_stream():
    """A gain the scorecard adds for one method draws from default_rng([seed, crc32(name)]); every gain the
    method shares with the card draws the zoo's values (hand-computed here), so adding one moves none of them."""
    import zlib

    from jaxapf.compare.select import random_candidates

    card = load_scorecard(folder=ROOT / "tests" / "data" / "scorecard-tiny")
    spec = card.for_method("basic+cbf")  # the filter's two gains are not the card's
    assert spec.selection.added == ("cbf_p1", "cbf_p2")
    sel = spec.selection
    ranges = dict(sel.ranges)
    shared = [g for g, _ in card.spec.selection.ranges]
    u = np.random.default_rng(2).uniform(size=(sel.candidates - 1, len(shared)))
    drawn = random_candidates(spec, "basic+cbf", 2)
    for j, cand in enumerate(drawn[1:]):
        values = cand.floats()
        for i, g in enumerate(shared):
            if g not in spec.method_gains("basic+cbf"):
                continue  # a gain it does not read keeps its default
            assert values[g] == pytest.approx(float(ranges[g].sample(np.array([u[j, i]]))[0]), rel=1e-12)
        for g in sel.added:
            v = np.random.default_rng([2, zlib.crc32(g.encode())]).uniform(size=sel.candidates - 1)[j]
            assert values[g] == pytest.approx(float(ranges[g].sample(np.array([v]))[0]), rel=1e-12)
    assert card.for_method("basic").selection.added == ()  # a member draws what the zoo drew


def test_a_folder_is_claimed_by_its_engine_and_recorded_plugins(tmp_path, monkeypatch):
    """claim: the first run records the engine and each plugin's sha256; a later one with the same, or with a
    plugin loaded beside them, goes on; an edited or missing recorded plugin, or another engine, is refused."""
    import jaxapf.spec.plugins as plugins
    from jaxapf.compare.scorecard import claim
    from jaxapf.validation import ConfigError

    monkeypatch.setattr(plugins, "plugin_digests", lambda: {"/p/mine.py": "a" * 64})
    first = claim(tmp_path)
    assert claim(tmp_path) == first
    monkeypatch.setattr(plugins, "plugin_digests", lambda: {"/p/mine.py": "a" * 64, "/p/other.py": "b" * 64})
    claim(tmp_path)  # a plugin beside the recorded one changes nothing recorded
    for now, said in (({"/p/mine.py": "c" * 64}, "(plugin mine.py changed)"), ({}, "(plugin mine.py changed)")):
        monkeypatch.setattr(plugins, "plugin_digests", lambda now=now: now)
        with pytest.raises(ConfigError, match=re.escape(said)):
            claim(tmp_path)
    monkeypatch.setattr(plugins, "plugin_digests", lambda: {"/p/mine.py": "a" * 64})
    (tmp_path / "identity.json").write_text(json.dumps(first | {"jaxlib": "0.0.elsewhere"}))
    with pytest.raises(ConfigError, match=re.escape("(jaxlib changed)")):
        claim(tmp_path)

# Draft, for tests/compare/test_scorecard.py once v1's zoo is stored (then remove scorecard-v1-zoo/).
# Not slow: it reads the stored files and recomputes the leaderboard (no flight).


def test_the_shipped_zoo_is_the_cards_complete_and_its_facts_are_its_leaderboard():
    """Scorecard v1's stored zoo: made under the card's digest; every member flew every test field of every family
    for each of its three selections (128 fields per family and seed); every (member, seed) selection is stored,
    each random search spending the budget exactly and the gradient search at most it; no two members' selections
    tie (the card's budget separates the zoo); and facts.json is the leaderboard recomputed from the stored
    episodes and selections, rank by rank and rate by rate."""
    from jaxapf.compare.scorecard import (facts, leaderboard, stored_episodes, stored_identity,
                                          stored_selections)

    card = load_scorecard("v1")
    assert stored_identity(card)["digest"] == card.digest
    zoo = stored_episodes(card)
    spec = card.spec
    counts = zoo.groupby(["member", "selection", "family"]).size()
    assert set(counts) == {spec.test.fields}
    assert len(counts) == len(spec.methods) * len(spec.selection.seeds) * len(spec.test.families)
    spent = stored_selections(card)
    assert sorted((s.method, s.seed) for s in spent) == sorted(
        (m, s) for m in spec.methods for s in spec.selection.seeds)
    for s in spent:
        if spec.selection.search_of(s.method) == "gradient":
            assert 0 < s.episodes <= spec.selection.budget
        else:
            assert s.episodes == spec.selection.budget
    found = json.loads((card.folder / "facts.json").read_text())
    assert found["selection_ties"] == []
    again = facts(card, leaderboard(zoo, None, spent=spent), spent)
    for key in ("rank", "episodes", "success", "success_lo", "success_hi", "collision", "selection_seconds",
                "identical", "selection_hours"):
        assert found[key] == again[key], key


# benchmarks/results/scorecard-basic.json (python benchmarks/record.py scorecard-basic, alone, empty cache):
def test_a_method_of_basics_cost_is_scored_in_minutes_and_reproduces_basic():
    import json as _json

    run = _json.loads((ROOT / "benchmarks" / "results" / "scorecard-basic.json").read_text())
    # check the record's keys first: runs.0.cold_s, compilation_cache, cpu_count, row_equals_basic,
    # primary_vs_basic verdicts
    assert run["cpu_count"] == 2 and "empty" in run["compilation_cache"]
    assert run["runs"][0]["cold_s"] <= 600
    assert run["row_equals_basic"] and set(run["primary_vs_basic"].values()) == {"equivalent"}

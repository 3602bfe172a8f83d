"""Scorecard v1 as shipped: its stored zoo is the card's and complete, its facts are its leaderboard recomputed,
the pages' words about it follow from them, and a method of ``basic``'s cost is ranked within the issue's ten
minutes reproducing ``basic`` (benchmarks/results/scorecard-basic.json). Reads files only: no flight."""

from __future__ import annotations

import json

from conftest import ROOT

from jaxapf.compare.scorecard import (
    facts,
    leaderboard,
    load_scorecard,
    stored_episodes,
    stored_identity,
    stored_selections,
)


def test_the_shipped_zoo_is_the_cards_complete_and_its_facts_are_its_leaderboard():
    """Made under the card's digest; every member flew every test field of every family for each of its three
    selections; every (member, seed) selection is stored, each random search spending the budget exactly and the
    gradient search at most it; no two members' selections tie (the card's budget separates the zoo: the page
    says so); and facts.json is the leaderboard recomputed from the stored episodes and selections."""
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
    page = (ROOT / "docs" / "scorecard.md").read_text().replace("\n", " ")
    assert "(a budget large enough separates the zoo: none)" in page
    again = facts(card, leaderboard(zoo, None, spent=spent), spent)
    for key in ("rank", "episodes", "success", "success_lo", "success_hi", "collision", "collision_lo",
                "collision_hi", "clearance_median", "selection_episodes", "selection_seconds", "family_success",
                "family_collision", "identical", "selection_hours", "protocol"):
        assert found[key] == again[key], key


def test_a_method_of_basics_cost_is_scored_in_minutes_and_reproduces_basic():
    """The record of ``python benchmarks/record.py scorecard-basic``: two cores, an empty compilation cache,
    within ten minutes; ``basic`` scored again reproduces its stored row and is *equivalent* to it on every
    primary comparison (success and collision, families pooled)."""
    run = json.loads((ROOT / "benchmarks" / "results" / "scorecard-basic.json").read_text())["runs"][0]
    assert run["environment"]["cpu_count"] == "2" and run["compilation_cache"] == "empty"
    assert run["cold_s"] <= 600
    assert run["members"] == len(load_scorecard("v1").spec.methods) + 1
    assert run["row_equals_basic"]
    assert sorted(v["metric"] for v in run["primary_vs_basic"]) == ["collision", "success"]
    assert {v["verdict"] for v in run["primary_vs_basic"]} == {"equivalent"}

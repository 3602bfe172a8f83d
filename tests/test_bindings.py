"""Every number of a bound document is the fact it names (tests/bindings.py), and every ±1 change of a
bound number's last digit or swap of a bound verdict word is caught: a mutation test over the documents
bound so far (it replaces, for them, the check that a number appears *somewhere* in a study's results, which
let 53 % of such changes through)."""

from __future__ import annotations

import pytest
from bindings import ROOT, mutations, problems
from test_readme_numbers import section

#: The documents (or a document's section, ``FILE#HEADING``) whose every number is bound (strict), and those
#: with some numbers bound.
STRICT = ["docs/performance.md", "analysis/README.md", "README.md#What the data says"]
PARTLY = ["README.md", "docs/tune.md", "docs/sweep.md", "docs/testing.md"]


def text_of(page: str) -> str:
    """A document, or its section from the ``## HEADING`` to the next ``## ``."""
    name, _, heading = page.partition("#")
    text = (ROOT / name).read_text()
    return section(text, heading) if heading else text


def test_a_bound_number_is_its_fact_at_the_precision_written():
    text = "ran 230,862<!--=bench/engine:runs.0.engine.steps_per_s--> steps/s, 305<!--=bench/engine:runs.0.speedup-->×"
    assert problems(text) == []
    assert problems(text.replace("230,862", "230,863")) and problems(text.replace("305", "306"))
    assert problems("230,861.5<!--=bench/engine:runs.0.engine.steps_per_s-->") == []
    assert problems("230,861.6<!--=bench/engine:runs.0.engine.steps_per_s-->")  # 230861.537: not this one
    # a ratio of two facts, a scale, a sign
    assert problems("305<!--=bench/engine:runs.0.engine.steps_per_s÷runs.0.oracle.steps_per_s-->") == []
    assert problems("47.7<!--=bench/engine:runs.0.engine.success_rate×100--> %") == []
    assert problems("−47.7<!--=bench/engine:-runs.0.engine.success_rate×100-->") == []
    assert problems("+47.7<!--=bench/engine:-runs.0.engine.success_rate×100-->")  # the sign is the fact's
    assert problems("falls by 47.7<!--=bench/engine:-runs.0.engine.success_rate×100-->") == []  # by size


def test_unbound_numbers_and_unknown_facts_are_named():
    found = problems("took 3.4 s and 7<!--=bench/engine:runs.0.nothing--> more, in study 11 (`N = 20`, 2026-11-25)")
    assert any("3.4 is bound to no fact" in p for p in found)
    assert any("no fact bench/engine:runs.0.nothing" in p for p in found)
    assert len(found) == 2  # "study 11", inline code and the date are identifiers, not reported numbers
    assert problems("took 3.4 s", strict=False) == []


def test_a_bound_verdict_is_its_facts_word():
    text = "CMA-ES is *worse*<!--=study/tuner_study:best_black_box_verdicts.full/d3.inconclusive-->"
    found = problems(text)
    assert found and "the fact" in found[0] and "is 6" in found[0]  # a count of another verdict
    assert problems("*worse*") and not problems("*worse*", strict=False)


def test_a_verdict_word_bound_to_a_count_is_the_counts_word():
    text = ("*worse*<!--=study/swarm_study:reciprocity_verdicts.swarm_success/worse--> in "
            "8<!--=study/swarm_study:reciprocity_verdicts.swarm_success/worse--> of 60")
    assert problems(text, strict=False) == []
    assert problems(text.replace("*worse*", "*better*"), strict=False)


def test_every_mutation_of_a_number_or_verdict_changes_one_thing():
    text = ("9<!--=bench/x:y--> and 10<!--=bench/x:y--> and 1,024<!--=bench/x:y--> and "
            "0.05<!--=bench/x:y--> and *better*<!--=bench/x:y-->")
    changed = {what for what, _ in mutations(text)}
    assert changed == {"9 -> 10", "9 -> 8", "10 -> 11", "10 -> 9", "1,024 -> 1,025",
                       "1,024 -> 1,023", "0.05 -> 0.06", "0.05 -> 0.04", "*better* -> *worse*",
                       "*better* -> *equivalent*", "*better* -> *inconclusive*"}


@pytest.mark.parametrize("page", STRICT + PARTLY)
def test_every_bound_number_is_its_fact(page):
    found = problems(text_of(page), strict=page in STRICT)
    assert not found, f"{page}: " + "\n".join(found[:20])


def _first_difference(a: str, b: str) -> int:
    """Where ``a`` and ``b`` first differ (they do): a bisection over prefixes, each compared at C speed."""
    lo, hi = 0, min(len(a), len(b))  # a[:lo] == b[:lo]; they differ within [:hi + 1]
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if a[:mid] == b[:mid] else (lo, mid - 1)
    return lo


def test_first_difference_is_the_first_differing_character():
    assert [_first_difference(a, b) for a, b in (("abc", "abd"), ("xbc", "abc"), ("ab", "abc"), ("a1,024", "a1,025"))] \
        == [2, 0, 2, 5]


def test_every_change_of_a_bound_number_or_verdict_is_caught():
    """At least 500 mutations over the bound documents, all caught. Each is checked where it was made (a
    binding reads only the text just before it): what :func:`problems` finds there must differ from what it
    finds in the same stretch of the unchanged document."""
    missed, total = [], 0
    for page in STRICT + PARTLY:
        text = text_of(page)
        for what, mutated in mutations(text):
            total += 1
            at = _first_difference(text, mutated)
            lo, hi = max(0, at - 120), at + 400
            if problems(mutated[lo:hi], strict=False) == problems(text[lo:hi + len(text) - len(mutated)],
                                                                   strict=False):
                missed.append(f"{page}: {what}")
    assert total >= 500, f"only {total} mutations: bind more of the documents"
    assert not missed, missed[:20]


def test_a_bound_answer_is_its_facts_word_and_the_rule_gives_that_word(monkeypatch):
    import bindings

    facts = {"answer": {"word": "Not shown", "verdicts": {"seed1": "inconclusive", "seed2": "worse"}},
             "wide": {"word": "No", "verdicts": {"seed1": "inconclusive", "seed2": "worse"}}}
    monkeypatch.setattr(bindings, "_source", lambda source: facts)
    text = "| Can it? | **Not shown<!--=study/x:answer-->.** The seeds disagree. |"
    assert problems(text) == []
    assert any("the fact study/x:answer is 'Not shown'" in p for p in problems(text.replace("Not shown", "No")))
    # a word wider than its verdicts: the fact itself breaks the rule
    assert any("verdicts allow 'Not shown'" in p for p in problems("**No<!--=study/x:wide-->.**"))
    assert any("bound to no answer fact" in p for p in problems("**No.** Nothing bound."))
    assert any("no answer fact" in p for p in problems("**No<!--=study/x:answer.verdicts.seed1-->.**"))
    caught = [what for what, changed in mutations(text) if problems(changed)]
    assert len(caught) == 4  # every other answer word

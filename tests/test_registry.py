"""The registry every component kind shares: names, refusals, the one-line errors, and the hook that
declares a component's gains when it is registered."""

from __future__ import annotations

import dataclasses

import pytest

import jaxapf.planners  # noqa: F401  (declares k_rep)
from jaxapf.gains import GAINS, GainSpec, declare_entry_gains
from jaxapf.registry import Registry
from jaxapf.validation import ConfigError


@dataclasses.dataclass(frozen=True)
class Thing:
    """A thing for the tests.

    More words."""

    gains: tuple = ()


def test_names_entries_and_lookups():
    r = Registry("thing")
    a, b = Thing(), Thing((GainSpec("registry_test_a", 1.0),))
    assert r.register("first", a) is a and r.register("second_2", b) is b
    assert r.names() == ("first", "second_2") and list(r) == ["first", "second_2"] and len(r) == 2
    assert r.get("first") is a and r["second_2"] is b and "first" in r and "third" not in r
    assert r.describe("first") == "A thing for the tests."
    custom = Registry("thing", describe=lambda t: f"``{len(t.gains)}`` gains")
    custom.register("b", b)
    assert custom.describe("b") == "1 gains"


@pytest.mark.parametrize("name", ["", "1abc", "a-b", "a b", None, 3])
def test_a_bad_name_is_refused(name):
    with pytest.raises(ConfigError, match="name .* must be letters, digits and '_'"):
        Registry("thing").register(name, Thing())


def test_a_second_entry_under_a_name_needs_replace_and_the_same_one_is_idempotent():
    r = Registry("thing")
    r.register("x", Thing())
    r.register("x", Thing())  # equal entry: no error
    other = Thing((GainSpec("registry_test_b", 2.0),))
    with pytest.raises(ConfigError, match="a thing named 'x' is registered already; pass replace=True"):
        r.register("x", other)
    assert r.register("x", other, replace=True) is r.get("x")


def test_an_unknown_name_is_one_line_naming_where_and_the_choices():
    r = Registry("planner")
    r.register("basic", Thing())
    with pytest.raises(ConfigError, match=r"^sim\.method = 'nope' is not a registered planner; choose one of basic$"):
        r.get("nope", "sim.method")
    with pytest.raises(ConfigError, match="choose one of \\(none registered\\)"):
        Registry("metric").get("x")


def test_registering_runs_the_hook_first_and_a_refused_declaration_registers_nothing():
    seen = []
    r = Registry("thing", on_register=seen.append)
    a = Thing()
    r.register("a", a)
    assert seen == [a]
    # the hook of every component registry: a gain declared otherwise than before is refused, and the
    # component is not entered (k_rep is the planners' gain, default 10)
    components = Registry("thing", on_register=declare_entry_gains)
    clash = Thing((GainSpec("k_rep", 99.0, low=0.0),))
    with pytest.raises(ConfigError, match="gain 'k_rep' is declared already"):
        components.register("clash", clash)
    assert "clash" not in components and GAINS.get("k_rep").default == 10.0
    same = Thing((GAINS.get("k_rep"),))
    assert components.register("same", same) is same

"""The schema every spec is read with (jaxapf.spec.schema): unknown, missing and defaulted keys, the shared
readers and the grids, each refusal one line naming its key."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.spec.schema import OMIT, REQUIRED, SEED, Key, Table, integer, names, number, spec_name, value_grid
from jaxapf.validation import MAX_SEED, ConfigError

TABLE = Table({"size": Key(integer(1, 10), REQUIRED, "give the size"), "scale": Key(number(0.0, lo_open=True), 2),
               "note": Key(lambda where, value: str(value), OMIT),
               "inner": Key(Table({"seed": Key(SEED, 7)}), {})})


def test_a_table_reads_given_keys_and_defaults_alike_in_order():
    assert TABLE("t", {"size": 3}) == {"size": 3, "scale": 2.0, "inner": {"seed": 7}}
    assert list(TABLE("t", {"note": 5, "size": 1})) == ["size", "scale", "note", "inner"]
    assert TABLE("", {"size": 2, "inner": {"seed": 0}})["inner"] == {"seed": 0}


@pytest.mark.parametrize("value, message", [
    ({"size": 3, "sise": 1}, "t.sise is not a known key (did you mean `size`?); allowed: size, scale, note, inner"),
    ({}, "t.size is missing; give the size"),
    ({"size": 11}, "t.size = 11 is out of range"),
    ({"size": 3, "scale": 0}, "t.scale = 0.0 is out of range; allowed: a finite number > 0"),
    ({"size": 3, "scale": True}, "t.scale = True must be a number"),
    ({"size": 3, "inner": {"seed": -1}}, "t.inner.seed = -1 is out of range"),
    ({"size": 3, "inner": 4}, "t.inner must be a table, got 4"),
    ([], "t must be a table"),
])
def test_a_bad_table_is_one_line_naming_the_key(value, message):
    with pytest.raises(ConfigError) as info:
        TABLE("t", value)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_the_shared_readers():
    assert number(0.0, lo_open=True, inf=True)("x", math.inf) == math.inf
    with pytest.raises(ConfigError, match="x = inf is out of range"):
        number(0.0)("x", math.inf)
    assert names(("a", "b", "c"), canonical=True)("x", ["c", "a"]) == ("a", "c")
    assert SEED("s", MAX_SEED) == MAX_SEED
    with pytest.raises(ConfigError, match=r"name = 'a b' must be a string of letters, digits, '_', '.', '-' \(why\)"):
        spec_name("why")("name", "a b")


GRID = value_grid(lambda where, key, value: integer(0, 9)(where, value), keys=("a", "b"), empty="g is empty")


def test_a_grid_reads_every_value_and_refuses_repeats_and_sizes():
    assert GRID("g", {"b": [1, 2], "a": [0]}) == (("b", (1, 2)), ("a", (0,)))
    for value, message in [({}, "g is empty"), ({"c": [1]}, "g.c is not a known key; allowed: a, b"),
                           ({"a": 1}, "g.a = 1 must be a list of values"), ({"a": []}, "g.a is empty"),
                           ({"a": [1, 10]}, "g.a[1] = 10 is out of range"),
                           ({"a": [1, 2, 1]}, "g.a[2] = 1 repeats an earlier value")]:
        with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
            GRID("g", value)
    big = value_grid(lambda where, key, value: value, empty="")
    with pytest.raises(ConfigError, match="g expands to 160,000 settings; at most 100,000 are allowed"):
        big("g", {"a": list(range(400)), "b": list(range(400))})


@given(st.dictionaries(st.sampled_from(["a", "b"]), st.lists(st.integers(0, 9), min_size=1, max_size=10, unique=True),
                       min_size=1))
@settings(max_examples=50, deadline=None)
def test_a_grid_keeps_what_it_is_given(table):
    assert GRID("g", table) == tuple((k, tuple(v)) for k, v in table.items())

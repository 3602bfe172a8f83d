"""The registry every component kind shares: names, refusals, the one-line errors, and the hook that
declares a component's gains when it is registered."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

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
    r = Registry("thing", on_register=(lambda entry, registry: seen.append((entry, registry)),))
    a = Thing()
    r.register("a", a)
    assert seen == [(a, r)]
    # the hook of every component registry: a gain declared otherwise than before is refused, and the
    # component is not entered (k_rep is the planners' gain, default 10)
    components = Registry("thing", on_register=(declare_entry_gains,))
    clash = Thing((GainSpec("k_rep", 99.0, low=0.0),))
    with pytest.raises(ConfigError, match="gain 'k_rep' is declared already"):
        components.register("clash", clash)
    assert "clash" not in components and GAINS.get("k_rep").default == 10.0
    same = Thing((GAINS.get("k_rep"),))
    assert components.register("same", same) is same


def test_a_ranked_registry_lists_by_rank_then_registration():
    rank = {"c": 1, "a": 0, "b": 1, "d": 0}
    r = Registry("thing", rank=rank.__getitem__)
    for name in "cabd":
        r.register(name, Thing())
    assert r.names() == ("a", "d", "c", "b") and list(r) == ["a", "d", "c", "b"]
    assert [n for n, _ in r.items()] == ["a", "d", "c", "b"]


_ORDER = """
import {first}, jaxapf
jaxapf.Gains
from jaxapf.gains import GAINS
from jaxapf.metrics import METRICS
print(" ".join(GAINS.names())); print(" ".join(METRICS.names()))
"""


@pytest.mark.parametrize("first", ["jaxapf.world.quadrotor", "jaxapf.world.sensing", "jaxapf.control.cbf"])
def test_gains_and_metrics_are_listed_alike_whichever_module_is_imported_first(first):
    """The gain columns, the metric columns and a tuner's parameter vector follow the registries' order:
    by kind of component in the loop, then declaration, never by which module a program imported first
    (importing the quadrotor first once put its gains before the planners')."""
    canonical = subprocess.run([sys.executable, "-c", _ORDER.format(first="jaxapf")], capture_output=True,
                               text=True, check=True).stdout.splitlines()
    gains, metrics = subprocess.run([sys.executable, "-c", _ORDER.format(first=first)], capture_output=True,
                                    text=True, check=True).stdout.splitlines()
    assert [gains, metrics] == canonical
    assert gains.split()[:2] == ["gamma", "k"]  # the planners' first
    # the episode's own first, then by component kind
    assert metrics.split()[-7:] == ["vo_infeasible_steps", "vo_truncated_steps", "cbf_infeasible_steps",
                                    "cbf_truncated_steps", "max_tilt", "saturation_time", "unseen_steps"]


_OWNER = """
import dataclasses
from jaxapf.metrics import Metric, metric_names
from jaxapf.world import Plant, register_plant

@dataclasses.dataclass(frozen=True)
class Owner(Plant):
    metrics = (Metric("owned", lambda ctx: ctx.extra("owned"), unit="s"),)
    def init(self, start, gains, sim): ...
    def kinematics(self, state): ...
    def step(self, state, accel, disturbance, gains, sim): ...
    def linear_model(self, dt, dtype): ...

register_plant("owner", Owner())
print(" ".join(metric_names()))
"""


def test_a_component_registers_the_metrics_it_owns_among_its_kinds():
    """Registering a component registers its ``metrics``: after the episode's own, with its kind (a plant's
    before the sensors'), in a second process so that this one's registry stays as built."""
    from jaxapf.control import CBF
    from jaxapf.metrics import METRICS
    from jaxapf.world import NoisySensor, Quadrotor

    assert METRICS.get("cbf_infeasible_steps") is CBF.metrics[0]
    assert [METRICS.get(m.name) for m in Quadrotor.metrics] == list(Quadrotor.metrics)
    assert METRICS.get("unseen_steps") is NoisySensor.metrics[0]
    names = subprocess.run([sys.executable, "-c", _OWNER], capture_output=True, text=True,
                           check=True).stdout.split()
    assert names.index("spl") < names.index("saturation_time") < names.index("owned") < names.index("unseen_steps")

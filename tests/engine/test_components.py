"""The components table: which registry each static key names, and which gains a setting reads."""

from __future__ import annotations

import pytest

import jaxapf
from jaxapf.config import SimConfig
from jaxapf.engine import COMPONENTS, gains_read
from jaxapf.engine.components import component_names
from jaxapf.validation import ConfigError


def test_every_static_key_names_its_registry():
    assert COMPONENTS == {"method": jaxapf.PLANNERS, "filter": jaxapf.FILTERS, "plant": jaxapf.PLANTS,
                          "sensor": jaxapf.SENSORS, "disturbance": jaxapf.DISTURBANCES}
    sim = SimConfig.from_flat(method="vortex", filter="cbf", plant="quadrotor", sensor="noisy", disturbance="wind")
    assert component_names(sim) == {"method": "vortex", "filter": "cbf", "plant": "quadrotor", "sensor": "noisy",
                                    "disturbance": "wind"}


def test_a_setting_reads_the_gains_its_components_declare():
    # by hand: basic declares k_rep, d_s, k_att, eta; the default filter, plant, sensor and disturbance none
    assert gains_read(SimConfig.from_flat(method="basic")) == {"k_rep", "d_s", "k_att", "eta"}
    with_cbf = gains_read(SimConfig.from_flat(method="direction_velocity", filter="cbf"))
    assert with_cbf == {"k_rep", "d_s", "k_att", "eta", "gamma", "k", "cbf_p1", "cbf_p2"}
    every = SimConfig.from_flat(method="vortex", filter="cbf", plant="quadrotor", sensor="noisy", disturbance="wind")
    declared = {g.name for key, registry in COMPONENTS.items() for g in registry.get(every.flat()[key]).gains}
    assert gains_read(every) == declared


def test_an_unknown_component_is_one_line_naming_its_key():
    sim = SimConfig.from_flat(method="basic")
    with pytest.raises(ConfigError, match=r"sim\.filter"):
        from jaxapf.engine import components_read_gains
        components_read_gains(component_names(sim) | {"filter": "no_such_filter"})

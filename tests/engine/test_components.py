"""The components table: which registry each static key names, and which gains a setting reads."""

from __future__ import annotations

import pytest

import jaxapf
from jaxapf.config import SimConfig
from jaxapf.engine import COMPONENTS, gains_read
from jaxapf.engine.components import component_names
from jaxapf.validation import ConfigError


def test_every_static_key_names_its_registry():
    from jaxapf.control import ESTIMATORS

    assert COMPONENTS == {"method": jaxapf.PLANNERS, "filter": jaxapf.FILTERS, "plant": jaxapf.PLANTS,
                          "sensor": jaxapf.SENSORS, "disturbance": jaxapf.DISTURBANCES, "estimator": ESTIMATORS}
    sim = SimConfig.from_flat(method="vortex", filter="cbf", plant="quadrotor", sensor="noisy", disturbance="wind",
                              estimator="observer")
    assert component_names(sim) == {"method": "vortex", "filter": "cbf", "plant": "quadrotor", "sensor": "noisy",
                                    "disturbance": "wind", "estimator": "observer"}


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


_PEEKING = """
import dataclasses
import jax.numpy as jnp
import jaxapf
from jaxapf.scenarios import family_params, make_scenarios

base = jaxapf.PLANNERS.get("basic")

@dataclasses.dataclass(frozen=True)
class Peeking(type(base)):
    def reference(self, state, x, t, goal, obstacles, gains, sim, horizon):
        return type(base).reference(self, state, x, t, goal, obstacles, gains.replace(k_rep=gains.cbf_p1), sim,
                                    horizon)

jaxapf.register_planner("peeking", Peeking(base.weight))
fields = make_scenarios(0, family_params("crossing"), jnp.arange(1))
try:
    jaxapf.evaluate(fields, jaxapf.Gains(), jaxapf.SimConfig.from_flat(method="peeking", t_max=1.0),
                    jaxapf.MPCConfig(horizon=4, iters=2))
except AttributeError as err:
    print(err)
"""


def test_a_component_sees_only_the_gains_its_setting_declares():
    """The closed loop hands the components the gains they declare (gains_read), nothing else: a planner
    reading a filter's gain fails while it is traced, naming the gain and those it may read (a second
    process keeps this one's planner registry as built)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _PEEKING], capture_output=True, text=True, check=True).stdout
    assert out.startswith("no gain 'cbf_p1' here (misspelled, or not declared"), out
    assert out.rstrip().endswith("gains: k_rep, d_s, k_att, eta"), out


def test_a_list_of_a_gain_no_component_reads_still_counts_its_settings():
    import numpy as np

    from jaxapf.config import MPCConfig
    from jaxapf.scenarios import family_params, make_scenarios

    fields = make_scenarios(0, family_params("crossing"), np.arange(2))
    sim, mpc = SimConfig.from_flat(method="basic", t_max=1.0), MPCConfig(horizon=4, iters=2)
    out = jaxapf.evaluate(fields, jaxapf.Gains(cbf_p1=[1.0, 2.0, 3.0]), sim, mpc)
    assert out["min_clearance"].shape == (3, 2)
    assert all(np.array_equal(out["min_clearance"][0], row) for row in out["min_clearance"])

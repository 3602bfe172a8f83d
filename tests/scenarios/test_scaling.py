"""``FamilyParams.scaled``: a family shrunk to another vehicle is the same fields in other units."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.scenarios import FAMILIES, family_params, make_scenarios
from jaxapf.scenarios.swarms import SWARM_FAMILIES, make_swarms, swarm_params
from jaxapf.spec.scenario import spec_family_params
from jaxapf.validation import ConfigError


@pytest.mark.parametrize("registry", [FAMILIES, SWARM_FAMILIES], ids=["families", "swarms"])
def test_every_parameter_of_every_family_declares_its_unit(registry):
    for name in registry.names():
        cls = registry.get(name, "family").params
        assert set(cls.UNITS) == {f.name for f in dataclasses.fields(cls)}, name


def test_scaled_by_hand():
    p = family_params("crossing").scaled(length=0.25, speed=0.5)
    assert p.distance == (5.0, 7.5) and p.radius == (0.125, 0.25) and p.r_uav == 0.075
    assert p.speed == (0.25, 0.75) and p.uav_speed == 0.8
    assert p.timing == (-1.0, 1.0) and p.t_max == 30.0  # times x length / speed
    assert p.count == (1, 3) and p.meet == (0.3, 0.7) and p.heading == (0.0, 360.0)  # counts, fractions, angles
    c = family_params("clutter").scaled(length=0.5)
    assert c.density == 16.0 and c.width == 6.0  # as many obstacles per field


def _close(a, b, scale, slack=0.0):
    np.testing.assert_allclose(np.asarray(a), scale * np.asarray(b), rtol=2e-5,
                               atol=1e-5 * max(scale, 1.0) + slack)


@settings(max_examples=12, deadline=None)
@given(family=st.sampled_from(FAMILIES.names()), length=st.floats(0.1, 3.0), speed=st.floats(0.2, 3.0),
       seed=st.integers(0, 1000))
def test_a_scaled_field_is_the_original_in_other_units(family, length, speed, seed):
    """Same key: every position × length, radius × length, velocity × speed; the same obstacles and kinds. An
    obstacle ``clear_endpoints`` pushed off the start or goal moves ``margin`` + a fixed 1 mm: its centre is
    off by at most that millimetre times ``|1 - length|``."""
    from jaxapf.scenarios.generate import _PUSH_SLACK

    base = family_params(family)
    a, b = make_scenarios(seed, base, 6), make_scenarios(seed, base.scaled(length, speed), 6)
    np.testing.assert_array_equal(a.obstacles.valid, b.obstacles.valid)
    np.testing.assert_array_equal(a.kind, b.kind)
    valid = np.asarray(a.obstacles.valid)
    for leaf in ("start", "goal"):
        _close(getattr(b, leaf), getattr(a, leaf), length)
    _close(np.asarray(b.obstacles.position)[valid], np.asarray(a.obstacles.position)[valid], length,
           _PUSH_SLACK * abs(1.0 - length) * 1.001)
    _close(np.asarray(b.obstacles.radius)[valid], np.asarray(a.obstacles.radius)[valid], length)
    _close(np.asarray(b.obstacles.velocity)[valid], np.asarray(a.obstacles.velocity)[valid], speed)


@pytest.mark.parametrize("family", SWARM_FAMILIES.names())
def test_a_scaled_swarm_is_the_original_in_other_units(family):
    base = swarm_params(family)
    a, b = make_swarms(3, base, 4), make_swarms(3, base.scaled(0.25, 0.5), 4)
    for leaf in ("start", "goal"):
        _close(getattr(b, leaf), getattr(a, leaf), 0.25)
    valid = np.asarray(a.obstacles.valid)
    _close(np.asarray(b.obstacles.position)[valid], np.asarray(a.obstacles.position)[valid], 0.25, 0.75e-3)


def test_a_spec_variant_scales_the_family_it_names_after_its_own_values():
    p = spec_family_params("crossing_cf", {"family": "crossing", "speed": [2.0, 4.0],
                                           "scale": {"length": 0.25, "speed": 0.5}})
    assert p == family_params("crossing", speed=(2.0, 4.0)).scaled(0.25, 0.5)
    assert spec_family_params("trap_cf", {"family": "trap", "scale": {"length": 1.0}}) == family_params("trap")
    for bad, where in (({"length": 0.0}, "scale.length"), ({"lenght": 0.5}, "scale.lenght"),
                       (0.5, "scale")):
        with pytest.raises(ConfigError, match=rf"scenario\.params\.trap_cf\.{where}"):
            spec_family_params("trap_cf", {"family": "trap", "scale": bad})


def test_a_sweep_spec_scales_a_variant_once_and_keeps_its_values_in_the_familys_units():
    from jaxapf.sweep import SweepSpec, parse_spec

    table = {"family": "crossing", "speed": [2.0, 4.0], "scale": {"length": 0.25, "speed": 0.5}}
    spec = parse_spec({"name": "s", "scenario": {"families": ["crossing_cf"], "fields": 2,
                                                 "params": {"crossing_cf": table}}})
    assert spec.params["crossing_cf"] == table
    assert spec.family_params("crossing_cf") == family_params("crossing", speed=(2.0, 4.0)).scaled(0.25, 0.5)
    again = SweepSpec.from_json(spec.to_json())  # as a dataset stores it
    assert again.family_params("crossing_cf") == spec.family_params("crossing_cf") and again.hash == spec.hash

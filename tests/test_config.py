"""Configuration validation: every bad value is rejected before tracing, naming field and range."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.gains import Gains, gains_from_mapping, load_gains
from jaxapf.validation import BoundWarning, ConfigError


@pytest.mark.parametrize(
    "kwargs,message",
    [
        (dict(gamma=-0.1), r"gains\.gamma = -0\.1 is out of range; allowed: a finite number >= 0"),
        (dict(k=-1.0), r"gains\.k = -1\.0 .*>= 0"),
        (dict(k_rep=0.0), r"gains\.k_rep = 0\.0 .*> 0"),
        (dict(d_s=0.0), r"gains\.d_s = 0\.0 .*> 0"),
        (dict(d_s=-2.0), r"gains\.d_s = -2\.0"),
        (dict(k_att=math.nan), r"gains\.k_att = nan"),
        (dict(eta=math.inf), r"gains\.eta = inf"),
        (dict(gamma=np.array([0.5, -1.0])), r"gains\.gamma = -1\.0"),
        (dict(gamma="high"), r"gains\.gamma = 'high' is not numeric"),
    ],
)
def test_bad_gains(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        Gains(**kwargs)


def test_k_above_one_warns_but_is_allowed():
    with pytest.warns(BoundWarning, match="k > 1"):
        Gains(k=1.5)


@pytest.mark.parametrize(
    "kwargs,message",
    [
        (dict(horizon=0), r"mpc\.horizon = 0 is out of range; allowed: an integer >= 1"),
        (dict(horizon=2.5), r"mpc\.horizon = 2\.5 must be an integer"),
        (dict(iters=0), r"mpc\.iters = 0"),
        (dict(q_pos=-1.0), r"mpc\.q_pos = -1\.0 .*>= 0"),
        (dict(q_vel=(1.0, 2.0)), r"mpc\.q_vel must be a number or 3 numbers"),
        (dict(r=0.0), r"mpc\.r = 0\.0 .*> 0"),
        (dict(f_pos=math.nan), r"mpc\.f_pos = nan"),
        (dict(v_penalty=-1.0), r"mpc\.v_penalty = -1\.0"),
    ],
)
def test_bad_mpc(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        MPCConfig(**kwargs)


@pytest.mark.parametrize(
    "kwargs,message",
    [
        (dict(a_max=0.0), r"sim\.a_max = 0\.0 is out of range; allowed: a finite number > 0"),
        (dict(a_max=-3.0), r"sim\.a_max = -3\.0"),
        (dict(v_max=math.nan), r"sim\.v_max = nan"),
        (dict(dt=0.0), r"sim\.dt = 0\.0"),
        (dict(t_max=0.01), r"sim\.t_max = 0\.01 must be at least one step"),
        (dict(r_uav=-0.1), r"sim\.r_uav = -0\.1 .*>= 0"),
        (dict(d_min=0.0), r"sim\.d_min = 0\.0"),
        (dict(method=""), r"sim\.method = '' must be a name"),
        (dict(bogus=1.0), r"sim\.bogus is not a simulation setting; allowed: method, filter, estimator, convention"),
        (dict(convention="reversed"), r"sim\.convention = 'reversed' is not allowed; choose one of intent, literal"),
        (dict(att_cap=-1.0), r"sim\.att_cap = -1\.0"),
        (dict(reference_velocity="yes"), r"sim\.reference_velocity = 'yes' must be true or false"),
    ],
)
def test_bad_sim(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        SimConfig.from_flat(**kwargs)


def test_static_configs_are_hashable_and_equal_by_value():
    assert hash(SimConfig()) == hash(SimConfig())
    assert MPCConfig(q_pos=2.0) == MPCConfig(q_pos=(2.0, 2.0, 2.0))
    assert SimConfig.from_flat(t_max=30.0, dt=0.1).episode.steps == 300
    sim = SimConfig.from_flat(method="basic", a_max=2.0, v_stall=0.2)
    assert (sim.planner.method, sim.vehicle.a_max, sim.metrics.v_stall) == ("basic", 2.0, 0.2)
    assert SimConfig.from_flat(sim.flat()) == sim and sim.replace(dt=0.05).episode.dt == 0.05


def test_component_names_are_checked_where_a_program_is_built():
    """Names of planners, filters and plants are checked against their registries when a closed loop is
    built (configuration depends on no component), naming the key and the registered choices."""
    import jax.numpy as jnp

    from jaxapf import Obstacles, Scenario, rollout

    scenario = Scenario(jnp.zeros(3), jnp.ones(3), Obstacles.empty(1))
    for key, message in (("method", r"sim\.method = 'vortx' is not a registered planner \(did you mean `vortex`\?\); "
                                    r"choose one of basic, "
                                    r"direction, direction_velocity"),
                         ("filter", r"sim\.filter = 'vortx' is not a registered safety filter; choose one of none"),
                         ("plant", r"sim\.plant = 'vortx' is not a registered plant; choose one of double_integrator")):
        with pytest.raises(ConfigError, match=message):
            rollout(scenario, Gains(), SimConfig.from_flat({key: "vortx", "t_max": 0.2}), MPCConfig(horizon=2))


@settings(max_examples=50, deadline=None)
@given(st.floats(allow_nan=True, allow_infinity=True))
def test_any_float_is_accepted_iff_in_range(x):
    ok = math.isfinite(x) and 0 < x <= np.finfo(np.float32).max
    if ok:
        assert Gains(d_s=x).d_s == x
    else:
        with pytest.raises(ConfigError, match="gains.d_s"):
            Gains(d_s=x)


def test_float32_overflow_is_a_validation_error():
    with pytest.raises(ConfigError, match=r"gains\.k_rep = 1e\+39 is too large: gains are computed in float32"):
        Gains(k_rep=1e39)


def test_gains_file(tmp_path):
    path = tmp_path / "g.toml"
    path.write_text("[gains]\ngamma = 2.0\nk = 0.25\n")
    assert load_gains(path) == Gains(gamma=2.0, k=0.25)
    path.write_text("gamma = 3\n")  # top-level keys, the fragment `jaxapf tune` writes
    assert load_gains(path).gamma == 3.0
    path.write_text("[gains]\ngama = 2.0\n")
    with pytest.raises(ConfigError, match=r"gains\.gama is not a gain; allowed: gamma, k, k_rep"):
        load_gains(path)
    path.write_text("[gains]\nd_s = -1\n")
    with pytest.raises(ConfigError, match=r"g\.toml:gains\.d_s = -1\.0 is out of range"):
        load_gains(path)  # the message names the file the bad value came from
    path.write_text("[gains]\nk = 1.5\n")
    with pytest.warns(BoundWarning, match=r"g\.toml:gains\.k > 1") as record:
        assert load_gains(path).k == 1.5
    assert len(record) == 1
    with pytest.raises(ConfigError, match="does not exist"):
        load_gains(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match=r"x\.gamma = 'a' must be a number"):
        gains_from_mapping({"gamma": "a"}, where="x")

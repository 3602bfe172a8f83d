"""``jaxapf tune`` on an array-valued gain (the learned weight's parameters): θ's map, the gradient estimators
over many coordinates, separable CMA-ES, the gains file it writes and the sweep that reads it back."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxapf.gains import Gains, load_gains
from jaxapf.planners.learned import SIZE, initial_params
from jaxapf.sweep import load_spec
from jaxapf.tune.estimators import episode_gradient
from jaxapf.tune.objective import Reparam
from jaxapf.tune.spec import parse_tune_spec
from jaxapf.validation import ConfigError

#: The learned weight's parameters and k_rep, trained for 3 steps of 2 fields on short runs.
LEARNED = {
    "name": "learned-micro",
    "train": {"families": ["crossing", "trap"], "fields_per_step": 2, "steps": 3, "validate_every": 3,
              "learning_rate": 0.05, "patience": 10},
    "validation": {"fields": 2, "seed": 1},
    "test": {"families": ["crossing"], "fields": 2, "seed": 2},
    "sim": {"method": "learned_weight", "t_max": 3.0, "horizon": 3, "iters": 4},
    "tune": {"params": ["omega_params", "k_rep"]},
    "scenario": {"params": {"crossing": {"distance": [4.0, 5.0]}, "trap": {"distance": [4.0, 5.0]}}},
    "search": {"grid": {"k_rep": [5.0, 10.0]}, "tuners": ["grid", "sep_cmaes"], "fields_per_setting": 2,
               "popsize": 4},
}


def test_theta_of_an_array_valued_gain_is_its_entries_and_flattens_in_declaration_order():
    theta_net = np.random.default_rng(0).normal(size=SIZE)
    rp = Reparam(("k_rep", "omega_params"), Gains(omega_params=theta_net, k_rep=3.0))
    assert rp.names == ("k_rep", "omega_params")  # declaration order, whatever order was asked
    with jax.enable_x64(True):
        theta = rp.theta(rp.base, jnp.float64)
        np.testing.assert_array_equal(theta["omega_params"], theta_net)  # unbounded: θ is the value itself
        flat = rp.flatten(theta)
        assert flat.shape == (1 + SIZE,) and flat[0] == float(theta["k_rep"])
        back = rp.unflatten(flat, jnp.float64)
        assert {k: np.asarray(v).tolist() for k, v in back.items()} == {k: np.asarray(v).tolist()
                                                                         for k, v in theta.items()}
        np.testing.assert_allclose(float(rp.gains(theta)["k_rep"]), 3.0, rtol=1e-12)


@pytest.mark.parametrize("estimator", ["smoothed", "zeroth", "blend"])
def test_an_estimator_over_a_gain_with_many_coordinates_is_the_estimator_over_its_flat_vector(estimator):
    """The perturbations, the estimate and its variance test see θ as one vector of coordinates: the same
    numbers whether θ is ``{k_rep, omega_params}`` or one flat gain holding both."""
    spec = parse_tune_spec({"train": {"estimator": estimator, "samples": 3, "sigma": 0.1}})
    rng = np.random.default_rng(1)
    weights = jnp.asarray(rng.normal(size=1 + SIZE))

    def split_loss(theta, scenario):
        x = jnp.concatenate([theta["k_rep"][None], theta["omega_params"]])
        return jnp.sum(weights * jnp.sin(x)), {}

    def flat_loss(theta, scenario):
        return jnp.sum(weights * jnp.sin(theta["all"])), {}

    with jax.enable_x64(True):
        x0 = jnp.asarray(rng.normal(size=1 + SIZE))
        key = jax.random.key(3)
        _, _, split = episode_gradient(split_loss, {"k_rep": x0[0], "omega_params": x0[1:]}, None, key, spec)
        _, _, flat = episode_gradient(flat_loss, {"all": x0}, None, key, spec)
        assert split["omega_params"].shape == (SIZE,) and split["k_rep"].shape == ()
        np.testing.assert_array_equal(np.concatenate([[split["k_rep"]], split["omega_params"]]), flat["all"])


def test_ranged_tuners_refuse_an_array_valued_gain():
    with pytest.raises(ConfigError, match="search.tuners: random draws each tuned gain from a range, but "
                                          "omega_params holds 1,217 numbers"):
        parse_tune_spec(LEARNED | {"search": LEARNED["search"] | {"tuners": ["random"]}})


@pytest.mark.slow
def test_a_learned_weight_trains_its_gains_file_names_its_spec_and_a_sweep_flies_it(tmp_path):
    """Three pathwise steps move the network, the separable CMA-ES mean moves from its start, the gains file
    holds the trained θ exactly beside the spec that trained it, and a sweep given that file flies it."""
    from jaxapf.tune.run import run_tune_spec

    spec = parse_tune_spec(LEARNED)
    summary = run_tune_spec(spec, json.dumps(LEARNED), tmp_path / "out", quiet=True)
    tuned = np.asarray(summary["gains"]["tuned"]["omega_params"])
    assert tuned.shape == (SIZE,) and np.all(np.isfinite(tuned)) and np.any(tuned != np.asarray(initial_params()))
    assert np.any(np.asarray(summary["gains"]["sep_cmaes"]["omega_params"]) != np.asarray(initial_params()))
    assert summary["budgets"]["sep_cmaes"]["episodes"] <= summary["budgets"]["tuning"]["episodes"]
    text = (tmp_path / "out" / "gains.toml").read_text()
    assert f"digest {summary['spec_digest']}" in text and '"learned_weight"' in text
    np.testing.assert_array_equal(load_gains(tmp_path / "out" / "gains.toml").omega_params, tuned)
    sweep = tmp_path / "s.toml"
    sweep.write_text('name = "s"\n[scenario]\nfamilies = ["crossing"]\nfields = 2\n[sim]\nmethod = "learned_weight"\n')
    flown = load_spec(sweep, tmp_path / "out" / "gains.toml").settings()[0].gains["omega_params"]
    assert flown == tuple(tuned.tolist())


def test_a_sweep_sets_an_array_valued_gain_per_setting_but_not_as_an_axis(tmp_path):
    from jaxapf.sweep import parse_spec

    base = {"name": "s", "scenario": {"families": ["crossing"], "fields": 2}}
    values = list(initial_params())
    for key, table in (("grid", {"omega_params": [values, values]}), ("random", {"n": 2, "omega_params": [0.0, 1.0]})):
        with pytest.raises(ConfigError, match="omega_params holds 1,217 numbers and cannot be a grid or random axis"):
            parse_spec(base | {key: table})
    other = [v + 0.5 for v in values]
    explicit = parse_spec(base | {"setting": [{"omega_params": values, "method": "learned_weight"},
                                              {"omega_params": other, "method": "learned_weight"}]})
    assert [s.gains["omega_params"] for s in explicit.settings()] == [tuple(values), tuple(other)]
    with pytest.raises(ConfigError, match=r"gains.omega_params = \[1.0, 2.0\] must|has shape \(2,\)"):
        parse_spec(base | {"gains": {"omega_params": [1.0, 2.0]}})
    spec = parse_spec(base | {"gains": {"omega_params": values}, "sim": {"method": "learned_weight"}})
    assert "omega_params" not in spec.gain_columns() and spec.settings()[0].gains["omega_params"] == tuple(values)


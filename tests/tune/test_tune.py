"""``jaxapf tune``: exact gradients, reparametrisation ranges, training, determinism, resume, spec checks."""

import json
import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from cli_capture import capture
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.cli import main
from jaxapf.datatypes import Obstacles, Scenario
from jaxapf.gains import GAINS, Gains, load_gains
from jaxapf.tune import train as tune_train
from jaxapf.tune.objective import Reparam, smooth_min
from jaxapf.tune.spec import parse_tune_spec
from jaxapf.tune.train import CHECKPOINT, TrainState, Tuner, episode_loss
from jaxapf.validation import BoundWarning, ConfigError

pytestmark = pytest.mark.slow  # module fixtures train and compare for tens of seconds

#: Every tunable number (the paper's six gains and those of the planners beyond it; tests/tune/test_array_gains.py
#: tunes the learned weight's array).
TUNABLE = tuple(n for n in Gains.names() if GAINS.get(n).tunable and not GAINS.get(n).shape)

#: A tuning problem small enough to train in a second (two families, 6 steps of 2 fields).
MICRO = {
    "name": "micro",
    "train": {"families": ["crossing", "trap"], "fields_per_step": 2, "steps": 6, "validate_every": 2,
              "learning_rate": 0.1, "patience": 10},
    "validation": {"fields": 2, "seed": 1},
    "test": {"families": ["crossing"], "fields": 2, "seed": 2},
    "sim": {"t_max": 3.0, "horizon": 3, "iters": 4},
    "scenario": {"params": {"crossing": {"distance": [4.0, 5.0]}, "trap": {"distance": [4.0, 5.0]}}},
    "search": {"grid": {"gamma": [0.5, 2.0]}, "random_n": 2, "tuners": ["grid", "random", "cmaes", "tpe"],
               "fields_per_setting": 2, "popsize": 4, "tpe_batch": 2},
}
MICRO_TOML = """name = "micro"
[train]
families = ["crossing", "trap"]
fields_per_step = 2
steps = 6
validate_every = 2
learning_rate = 0.1
patience = 10
[validation]
fields = 2
seed = 1
[test]
families = ["crossing"]
fields = 2
seed = 2
[sim]
t_max = 3.0
horizon = 3
iters = 4
[scenario.params.crossing]
distance = [4.0, 5.0]
[scenario.params.trap]
distance = [4.0, 5.0]
[search]
grid = { gamma = [0.5, 2.0] }
random_n = 2
tuners = ["grid", "random", "cmaes", "tpe"]
fields_per_setting = 2
popsize = 4
tpe_batch = 2
"""


def _two_obstacles(dtype) -> Scenario:
    """A static cylinder 0.22 m from the start (inside the 0.6 m margin) and a moving sphere; the
    goal is near, so with a small η the flow is not saturated and the gains matter."""
    obs = Obstacles(position=jnp.array([[1.0, 0.2, 2.0], [2.0, -1.0, 2.0]], dtype),
                    velocity=jnp.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype),
                    radius=jnp.array([0.5, 0.4], dtype), cylinder=jnp.array([True, False]),
                    valid=jnp.array([True, True]))
    return Scenario(start=jnp.array([0.0, 0.0, 2.0], dtype), goal=jnp.array([2.5, 1.0, 2.0], dtype), obstacles=obs)


STACK = ["gamma", "k", "k_rep", "d_s", "k_att", "eta", "cbf_p1", "cbf_p2", "mpc_pos", "mpc_vel", "mpc_terminal",
         "mpc_input", "mpc_speed"]


ESCAPE = ["t_detect", "t_escape", "d_escape"]


@pytest.mark.parametrize("stack", [{}, {"sim": {"filter": "cbf"}, "tune": {"params": STACK},
                                      "init": {"eta": 2.0, "k_rep": 0.01, "cbf_p1": 0.2, "cbf_p2": 0.3}},
                                   {"sim": {"filter": "cbf", "method": "direction_velocity_escape"},
                                    "tune": {"params": STACK + ESCAPE},
                                    "init": {"eta": 2.0, "k_rep": 0.01, "cbf_p1": 0.2, "cbf_p2": 0.3,
                                             "t_detect": 0.27, "t_escape": 0.53, "d_escape": 3.0}}],
                         ids=["planner", "planner+cbf+mpc", "planner+cbf+mpc+escape"])
def test_gradient_matches_central_differences_in_float64(stack):
    """Reverse mode through the scan over time (rematerialised, as in training), the APF reference
    flow, the unrolled FISTA and (second case: weak repulsion and slow CBF rates, so the filter acts) the
    CBF filter's QP and the MPC's matrices built from its traced weights, against central differences of
    the same float64 loss."""
    spec = parse_tune_spec({"sim": {"t_max": 1.0, "horizon": 3, "iters": 3} | stack.get("sim", {}),
                            "objective": {"d_safe": 0.6}, "init": stack.get("init", {"eta": 0.2, "k_rep": 1.0}),
                            **({"tune": stack["tune"]} if "tune" in stack else {})})
    assert set(spec.reparam.names) == set(stack.get("tune", {}).get("params", STACK[:6]))
    assert spec.train.remat
    with jax.enable_x64(True):
        scenario = _two_obstacles(jnp.float64)
        theta = spec.reparam.theta(spec.init, jnp.float64)
        value_and_grad = jax.jit(jax.value_and_grad(lambda th: episode_loss(th, scenario, spec), has_aux=True))
        (_, terms), grad = value_and_grad(theta)
        assert all(float(v) > 0 for v in terms.values())  # every term (collision included) is active
        loss = lambda th: float(value_and_grad(th)[0][0])  # noqa: E731
        h = 1e-6
        for name in theta:
            fd = (loss(theta | {name: theta[name] + h}) - loss(theta | {name: theta[name] - h})) / (2 * h)
            np.testing.assert_allclose(float(grad[name]), fd, rtol=1e-5, atol=1e-8, err_msg=name)
        assert max(abs(float(g)) for g in grad.values()) > 1e-2
        if "tune" in stack:  # naming the MPC's scales traces its weights; each gain moves the loss (the CBF acts)
            assert spec.sim.planner.mpc_weights == "gains"
            assert all(abs(float(grad[n])) > 0 for n in STACK if n.startswith(("mpc_", "cbf_")))
        if "t_detect" in theta:  # the UAV starts at rest, so an escape starts at 0.3 s: its distance moves the
            # loss, its switching times carry no gradient (central differences agree: the loss is flat in them)
            assert abs(float(grad["d_escape"])) > 0
            assert float(grad["t_detect"]) == 0.0 and float(grad["t_escape"]) == 0.0


@pytest.mark.filterwarnings("ignore::jaxapf.validation.BoundWarning")  # k > 1 is allowed, and warned about
@settings(max_examples=60, deadline=None)
@given(theta=st.lists(st.floats(allow_nan=False, allow_infinity=False, width=32), min_size=len(TUNABLE),
                     max_size=len(TUNABLE)),
       k_max=st.floats(0.01, 10.0))
def test_reparametrisation_keeps_every_gain_in_range(theta, k_max):
    reparam = Reparam(TUNABLE, Gains(), (("k", k_max),))
    # concrete values: Gains validates them itself too (ConfigError if out of range)
    gains = reparam.gains({n: jnp.float32(t) for n, t in zip(TUNABLE, theta)})
    values = {n: float(getattr(gains, n)) for n in TUNABLE}
    assert all(math.isfinite(v) for v in values.values())
    assert values["gamma"] >= 0.0
    assert 0.0 <= values["k"] <= k_max * (1 + 1e-6)
    assert all(values[n] > 0.0 for n in ("k_rep", "d_s", "k_att", "eta"))
    assert all(values[n] >= 0.0 for n in ("n_g", "k_v")) and values["d_escape"] > 0.0


def test_reparametrisation_inverts_and_rejects_unreachable_starts():
    reparam = Reparam(("gamma", "k", "d_s"), Gains(gamma=2.0, k=0.25, d_s=3.0))  # k's tuning range: [0, 1]
    gains = reparam.gains(reparam.theta(reparam.base, jnp.float32))
    np.testing.assert_allclose([gains.gamma, gains.k, gains.d_s], [2.0, 0.25, 3.0], rtol=1e-6)
    assert gains.k_rep == Gains().k_rep  # untuned gains stay
    with pytest.raises(ConfigError, match=r"init\.k = 1\.0 must lie strictly inside"):
        Reparam(("k",), Gains(k=1.0)).theta(Gains(k=1.0))
    with pytest.warns(BoundWarning):  # unbounded: k > 1 is allowed, and warned about
        assert float(Reparam(("k",), Gains(), (("k", math.inf),)).gains({"k": jnp.float32(30.0)}).k) > 1.0
    with pytest.raises(ConfigError, match=r"init\.gamma = 0\.0 must be > 0"):
        Reparam(("gamma",), Gains(gamma=0.0)).theta(Gains(gamma=0.0))


def test_smooth_min_ignores_padded_slots_exactly():
    x = jnp.array([0.7, 0.2, 123.0])
    valid = jnp.array([True, True, False])
    assert float(smooth_min(x, valid, 0.1)) == float(smooth_min(x[:2], valid[:2], 0.1))
    assert float(smooth_min(x, valid, 0.1)) <= 0.2
    assert float(smooth_min(x, valid, 1e-3)) == pytest.approx(0.2, abs=1e-6)


# --------------------------------------------------------------------------------------------
# training, determinism, resume, the command
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def command_run(tmp_path_factory):
    """The whole command on MICRO, as a user runs it."""
    root = tmp_path_factory.mktemp("tune")
    (root / "micro.toml").write_text(MICRO_TOML)
    assert main(["tune", str(root / "micro.toml"), "--out", str(root / "out"), "--quiet"]) == 0
    return root / "out"


def _same_state(a: TrainState, b: TrainState) -> None:
    for name in a.theta:
        assert np.array_equal(a.theta[name], b.theta[name]) and np.array_equal(a.best_theta[name], b.best_theta[name])
    for x, y in zip(jax.tree_util.tree_leaves(a.opt_state), jax.tree_util.tree_leaves(b.opt_state)):
        assert np.array_equal(x, y)
    assert json.dumps(a.history) == json.dumps(b.history)
    assert (a.step, a.best_step, a.best_val_loss) == (b.step, b.best_step, b.best_val_loss)


def test_training_lowers_the_loss_and_is_bit_deterministic(command_run, tmp_path):
    spec = parse_tune_spec(MICRO)
    state = Tuner(spec).train(tmp_path, quiet=True)
    assert state.step == 6 and state.validations == 4
    assert state.history[-1]["val_loss"] < state.history[0]["val_loss"]
    assert state.best_val_loss < state.history[0]["val_loss"]
    first_training = [r["loss"] for r in state.history[1:3]]
    last_training = [r["loss"] for r in state.history[-2:]]
    assert np.mean(last_training) < np.mean(first_training)
    reference = TrainState.load(command_run / CHECKPOINT, spec.digest(), Tuner(spec).initial_state())
    _same_state(state, reference)


def test_resume_after_a_kill_gives_the_uninterrupted_result(command_run, tmp_path, monkeypatch):
    spec = parse_tune_spec(MICRO)
    step = tune_train._train_step
    calls = []

    def killed_at_step_5(*args, **kwargs):
        calls.append(1)
        if len(calls) == 5:  # the last checkpoint was written after step 4
            raise KeyboardInterrupt
        return step(*args, **kwargs)

    monkeypatch.setattr(tune_train, "_train_step", killed_at_step_5)
    with pytest.raises(KeyboardInterrupt):
        Tuner(spec).train(tmp_path, quiet=True)
    monkeypatch.setattr(tune_train, "_train_step", step)
    assert TrainState.load(tmp_path / CHECKPOINT, spec.digest(), Tuner(spec).initial_state()).step == 4
    resumed = Tuner(spec).train(tmp_path, quiet=True)
    reference = TrainState.load(command_run / CHECKPOINT, spec.digest(), Tuner(spec).initial_state())
    _same_state(resumed, reference)


def test_command_writes_loadable_gains_and_a_summary(command_run):
    summary = json.loads((command_run / "summary.json").read_text())
    tuned = load_gains(command_run / "gains.toml")
    assert tuned.floats() == summary["gains"]["tuned"]
    assert summary["gains"]["default"] == Gains().floats()
    budget = summary["budgets"]
    assert budget["tuning"]["episodes"] == 6 * 2 + 4 * 2
    assert budget["grid"]["episodes"] == budget["random"]["episodes"] == 20  # 2 settings x 10 fields
    assert budget["cmaes"]["episodes"] == 16 and budget["cmaes"]["generations"] == 2  # 4 candidates x 2 fields
    assert budget["tpe"]["episodes"] == 20 and budget["tpe"]["settings"] == 10  # 5 batches of 2 trials x 2 fields
    assert all(budget[t]["seconds"] > 0 for t in ("grid", "random", "cmaes", "tpe"))
    rows = {(r["family"], r["setting"]) for r in summary["test"]}
    assert rows == {(f, s) for f in ("crossing", "all") for s in ("tuned", "default", "grid", "random", "cmaes", "tpe")}
    for name in ("history.csv", "training.png", "test.png", "test_results.csv", "test_episodes.parquet"):
        assert (command_run / name).stat().st_size > 0


def test_a_checkpoint_of_another_spec_is_refused(command_run):
    other = parse_tune_spec(MICRO | {"name": "other"})
    with pytest.raises(tune_train.TuneError, match="different spec"):
        Tuner(other).train(command_run, quiet=True)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"trian": {}}, r"trian is not a known key \(did you mean `train`\?\); allowed: name, plugins"),
        ({"train": {"learning_rat": 0.1}}, r"train\.learning_rat is not a known key"),
        ({"train": {"learning_rate": -1.0}}, r"train\.learning_rate = -1\.0 is out of range"),
        ({"train": {"optimizer": "adamm"}}, r"train\.optimizer = 'adamm' is not an optax optimiser"),
        ({"train": {"optimizer": "lbfgs"}}, r"train\.optimizer = 'lbfgs'"),
        ({"train": {"schedule": "linear"}}, r"train\.schedule = 'linear' is not allowed"),
        ({"train": {"families": ["crossing", "maze"]}}, r"train\.families\[1\] = 'maze' is not a family"),
        ({"train": {"fields_per_step": 1}}, r"train\.fields_per_step = 1 must be at least the number"),
        ({"train": {"remat": 1}}, r"train\.remat = 1 must be true or false"),
        ({"validation": {"seed": 0}}, r"train\.seed, validation\.seed and test\.seed must differ"),
        ({"objective": {"tau": 0.0}}, r"objective\.tau = 0\.0 is out of range"),
        ({"objective": {"w_colision": 1.0}}, r"objective\.w_colision is not a known key"),
        ({"tune": {"params": ["gamma", "kappa"]}}, r"tune\.params\.kappa is not a gain"),
        ({"tune": {"upper": {"k": 0.4}}}, r"init\.k = 0\.5 must lie strictly inside \(0, 0\.4\)"),
        ({"tune": {"upper": {"kappa": 0.4}}}, r"tune\.upper\.kappa is not a gain"),
        ({"init": {"d_s": -1.0}}, r"init\.d_s = -1\.0 is out of range"),
        ({"sim": {"horizn": 3}}, r"sim\.horizn is not a known key"),
        ({"sim": {"method": "magic"}}, r"sim\.method = 'magic' is not a registered planner"),
        ({"sim": {"dt": 0.0}}, r"sim\.dt = 0\.0 is out of range"),
        ({"scenario": {"params": {"trap": {"radius": [2.0, 1.0]}}}},
         r"scenario\.params\.trap\.radius .* is not an interval"),
        ({"scenario": {"trap": {"distance": [4.0, 5.0]}}},
         r"scenario\.trap is not allowed; .*\[scenario\.params\.trap\]"),
        ({"search": {"grid": {"gama": [1.0]}}}, r"search\.grid\.gama is not a gain"),
        ({"search": {"grid": {"gamma": [1.0, 2.0, 1]}}}, r"search\.grid\.gamma\[2\] = 1 repeats an earlier value"),
        ({"search": {"grid": {"k": [-1.0]}}}, r"search\.grid\.k = -1\.0 is out of range"),
        ({"train": {"steps": 0}}, r"train\.steps = 0 is out of range; allowed: an integer >= 1"),
        ({"train": {"steps": 10**6, "fields_per_step": 100}},
         r"train\.steps × train\.fields_per_step = 100,000,000 training fields; at most 4,194,304"),
        ({"search": {"random_n": 10**9}}, r"search\.random_n = 1000000000 is out of range; .* <= 100000"),
        ({"search": {"grid": {"gamma": [1.0 + i for i in range(400)], "k": [i / 400 for i in range(400)]}}},
         r"search\.grid expands to 160,000 settings; at most 100,000"),
        ({"test": {"fields": 5 * 10**9}}, r"test\.fields = 5000000000 is out of range"),
        ({"search": {"tuners": ["grid", "cma"]}}, r"search\.tuners\[1\] = 'cma' is not a tuner"),
        ({"search": {"cmaes_sigma": 0.0}}, r"search\.cmaes_sigma = 0\.0 is out of range"),
        ({"init": {"k_rep": 1e39}}, r"init\.k_rep = 1e\+39 is too large: gains are computed in float32"),
    ],
)
def test_spec_errors_name_the_key(change, message):
    data = {section: dict(value) if isinstance(value, dict) else value for section, value in MICRO.items()}
    for section, value in change.items():
        data[section] = data.get(section, {}) | value if isinstance(value, dict) else value
    with pytest.raises(ConfigError, match=message):
        parse_tune_spec(data)


def test_cli_reports_a_bad_spec_in_one_line(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("[train]\nsteps = -3\n")
    assert main(["tune", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.strip() == ("jaxapf tune: error: train.steps = -3 is out of range; allowed: an integer >= 1 and "
                           "<= 4194304")


def test_a_rerun_of_a_finished_tune_recomputes_nothing(command_run, capsys, monkeypatch):
    """Rerun on its finished folder, the command prints the test table and runs no episode."""
    before = {p.name: p.stat().st_mtime_ns for p in command_run.iterdir()}

    def no_episodes(*args, **kwargs):
        raise AssertionError("a finished tune ran episodes again")

    monkeypatch.setattr(Tuner, "report", no_episodes)
    spec = command_run.parent / "micro.toml"
    assert main(["tune", str(spec), "--out", str(command_run)]) == 0
    assert "already holds this tuning run (finished); nothing to do" in capsys.readouterr().err
    assert {p.name: p.stat().st_mtime_ns for p in command_run.iterdir()} == before


def test_an_interrupted_tune_reuses_its_finished_searches(command_run, tmp_path, monkeypatch, capsys):
    """Ctrl-C after the grid search: one line; the rerun reuses the grid search (searches.json) and
    ends with the same summary as the uninterrupted run."""
    from jaxapf.tune import proof
    from jaxapf.tune import searches as search_module

    spec = command_run.parent / "micro.toml"
    out = tmp_path / "out"
    searches = []
    select = proof.select_best

    def interrupted_after_grid(tuner, settings, budget, label):
        searches.append(label)
        if label == "random":
            raise KeyboardInterrupt
        return select(tuner, settings, budget, label)

    monkeypatch.setattr(search_module, "select_best", interrupted_after_grid)
    assert main(["tune", str(spec), "--out", str(out), "--quiet"]) == 130
    err = capsys.readouterr().err.strip()
    assert err == (f"jaxapf tune: interrupted; the last training checkpoint and finished searches are kept in {out}; "
                   "rerun the same command to resume")
    assert not (out / ".lock").exists() and "grid" in json.loads((out / "searches.json").read_text())
    searches.clear()

    def counted(tuner, settings, budget, label):
        searches.append(label)
        return select(tuner, settings, budget, label)

    monkeypatch.setattr(search_module, "select_best", counted)
    assert main(["tune", str(spec), "--out", str(out), "--quiet"]) == 0
    assert searches == ["random"]  # the grid search was reused (CMA-ES and TPE do not call select_best)
    mine, reference = (json.loads((d / "summary.json").read_text()) for d in (out, command_run))
    assert mine["gains"] == reference["gains"] and mine["test"] == reference["test"]


def test_a_second_tune_on_the_same_folder_refuses(tmp_path, capsys):
    from jaxapf.io.lock import OutputLock

    (tmp_path / "micro.toml").write_text(MICRO_TOML)
    with OutputLock(tmp_path / "out"):
        lock = json.loads((tmp_path / "out" / ".lock").read_text())
        lock["pid"], lock["start"] = 1, None  # a live process that is not this one
        (tmp_path / "out" / ".lock").write_text(json.dumps(lock))
        assert main(["tune", str(tmp_path / "micro.toml"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "is being written by pid 1" in err and "one writer" in err


def _quadratic_report(target: dict[str, float]):
    """A stand-in for :meth:`Tuner.report` whose loss is ``Σ (ln g - ln g*)²`` of each setting (no
    episode is flown): the black-box tuners' wiring (θ map, ranking direction, budget) against a known
    optimum."""
    def report(self, scenarios, settings):
        loss = np.array([sum((math.log(g[n]) - math.log(v)) ** 2 for n, v in target.items()) for g in settings])
        return {"loss": np.repeat(loss[:, None], scenarios.start.shape[0], axis=1)}
    return report


@pytest.mark.parametrize("tuner", ["cmaes", "sep_cmaes", "tpe"])
def test_black_box_tuners_find_a_known_minimum(tuner, tmp_path, monkeypatch):
    """With a loss whose minimum is known (k_rep = 2.5, eta = 0.4, the other gains free), each tuner
    given 600 evaluations ends far closer to it than the start gains, whose loss is ~0.9."""
    from jaxapf.tune.searches import SEARCHES

    spec = parse_tune_spec(MICRO | {"search": MICRO["search"] | {"fields_per_setting": 1, "popsize": 8,
                                                                  "tpe_batch": 4}})
    target = {"k_rep": 2.5, "eta": 0.4}
    monkeypatch.setattr(Tuner, "report", _quadratic_report(target))
    start = sum((math.log(spec.init[n]) - math.log(v)) ** 2 for n, v in target.items())
    found = SEARCHES[tuner](Tuner(spec), 600, tmp_path, spec.digest())["gains"]
    end = sum((math.log(found[n]) - math.log(v)) ** 2 for n, v in target.items())
    assert start > 0.5 and end < 0.05 * start


@pytest.mark.parametrize("tuner", ["cmaes", "sep_cmaes", "tpe"])
def test_an_interrupted_black_box_tuner_resumes_to_the_uninterrupted_result(tuner, tmp_path, monkeypatch):
    """Killed after its second generation or batch, the tuner's rerun (from ``search-NAME.json``) ends with
    the gains an uninterrupted run chose, bit for bit."""
    from jaxapf.tune.searches import SEARCHES

    spec = parse_tune_spec(MICRO)
    monkeypatch.setattr(Tuner, "report", _quadratic_report({"k_rep": 2.5, "eta": 0.4}))
    whole = SEARCHES[tuner](Tuner(spec), 64, tmp_path / "whole", spec.digest())
    report, calls = Tuner.report, []

    def killed_at_the_third(self, scenarios, settings):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return report(self, scenarios, settings)

    monkeypatch.setattr(Tuner, "report", killed_at_the_third)
    (tmp_path / "part").mkdir()
    with pytest.raises(KeyboardInterrupt):
        SEARCHES[tuner](Tuner(spec), 64, tmp_path / "part", spec.digest())
    monkeypatch.setattr(Tuner, "report", report)
    import json

    saved = json.loads((tmp_path / "part" / f"search-{tuner}.json").read_text())  # data: plain JSON, no pickle
    assert saved["digest"].startswith(spec.digest()) and not list((tmp_path / "part").glob("*.pkl"))
    resumed = SEARCHES[tuner](Tuner(spec), 64, tmp_path / "part", spec.digest())
    assert resumed["gains"].floats() == whole["gains"].floats() and resumed["episodes"] == whole["episodes"]


@pytest.mark.parametrize("estimator", ["smoothed", "zeroth", "blend"])
def test_training_with_a_perturbed_estimator_runs_counts_its_rollouts_and_is_deterministic(estimator, tmp_path):
    """Each perturbed estimator trains MICRO to a finite state, its budget counts 2·samples rollouts per
    training episode, and the same spec twice gives the same state (the perturbations are keyed by
    seed and step)."""
    from jaxapf.tune.proof import tuning_budget

    spec = parse_tune_spec(MICRO | {"train": MICRO["train"] | {"estimator": estimator, "samples": 2}})
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    state = Tuner(spec).train(tmp_path / "a", quiet=True)
    assert state.step == 6 and all(math.isfinite(float(v)) for v in state.theta.values())
    assert tuning_budget(spec, state)["training_episodes"] == 6 * 2 * 4
    again = Tuner(spec).train(tmp_path / "b", quiet=True)
    _same_state(state, again)


def test_a_tune_spec_traces_the_mpc_weights_it_tunes_or_scales():
    """Tuning an MPC scale, starting one away from 1 or gridding over one traces the weights; listing
    one at 1 does not."""
    mode = lambda data: parse_tune_spec(MICRO | data).sim.planner.mpc_weights  # noqa: E731
    assert mode({}) == "static" and mode({"init": {"mpc_pos": 1.0}}) == "static"
    assert mode({"tune": {"params": ["k_rep", "mpc_pos"]}}) == "gains"
    assert mode({"init": {"mpc_input": 2.0}}) == "gains"
    assert mode({"search": MICRO["search"] | {"grid": {"mpc_vel": [0.5, 1.0]}}}) == "gains"


def test_a_tune_specs_digest_stays_when_a_newer_setting_is_at_its_default():
    """A checkpoint belongs to its spec's digest: a static setting added later (``max_neighbours`` for
    swarms, ``projection_rows``, ``tracking``) at its default leaves every digest as it was, so runs started before it
    still resume."""
    import dataclasses

    from jaxapf.tune.spec import load_tune_spec

    spec, _ = load_tune_spec(pathlib.Path(__file__).resolve().parents[2] / "sweeps" / "tune-tiny.toml")
    assert spec.digest() == "b105fd45ad4cc8be85c938c37ec6fb2a8eb595f7e5830b08a2e462379bcf34c9"
    swarm = dataclasses.replace(spec, sim=spec.sim.replace(max_neighbours=8))
    assert swarm.digest() != spec.digest()
    assert dataclasses.replace(spec, sim=spec.sim.replace(projection_rows=8)).digest() != spec.digest()
    assert dataclasses.replace(spec, sim=spec.sim.replace(tracking="ideal")).digest() != spec.digest()


def test_a_checkpoint_whose_history_lacks_a_column_is_one_line(command_run, tmp_path):
    """A checkpoint edited or cut by hand (a history row without ``val_loss``) is bad input: one line
    naming the file, status 2, never a KeyError mid-training."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(command_run, out)
    with np.load(out / tune_train.CHECKPOINT) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["meta"]))
    meta["history"][0].pop("val_loss")
    arrays["meta"] = np.asarray(json.dumps(meta))
    with open(out / tune_train.CHECKPOINT, "wb") as fh:
        np.savez(fh, **arrays)
    (out / "summary.json").unlink()  # not finished: the run resumes from the checkpoint
    (tmp_path / "micro.toml").write_text(MICRO_TOML)
    rc, stdout, err = capture(main, ["tune", str(tmp_path / "micro.toml"), "--out", str(out), "--quiet"])
    assert rc == 2 and "checkpoint.npz is damaged" in err and "val_loss" in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_full_disk_while_tuning_is_one_line_keeping_what_was_finished(tmp_path, full_disk):
    full_disk(".history.csv")
    (tmp_path / "micro.toml").write_text(MICRO_TOML)
    rc, stdout, err = capture(main, ["tune", str(tmp_path / "micro.toml"), "--out", str(tmp_path / "out"), "--quiet"])
    assert rc == 2 and "(the file system is full)" in err and "checkpoint is kept" in err, err
    assert len(err.strip().splitlines()) == 1 and (tmp_path / "out" / tune_train.CHECKPOINT).is_file()

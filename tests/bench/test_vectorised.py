"""The vectorised numpy peer (jaxapf.bench.vectorised) against the JAX engine.

Same algorithm and iteration counts, so in float64 the two must agree to rounding on every field
of a batch (both conventions, cylinders, moving obstacles, padded slots, an active acceleration box
and the velocity penalty); in float32 to float32 rounding over a short episode.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import three_obstacle_field

from jaxapf.bench.engine import format_benchmark, run_benchmark
from jaxapf.bench.vectorised import vectorised_rollout
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Scenario
from jaxapf.engine import rollout
from jaxapf.gains import Gains
from jaxapf.scenarios import family_params, make_scenarios
from jaxapf.validation import ConfigError

GAINS = dict(gamma=1.3, k=0.7, k_rep=8.0, d_s=3.5, k_att=1.2, eta=0.6)


def _engine(scenarios, gains, sim, mpc):
    batched = jax.vmap(rollout, in_axes=(0, None, None, None))
    return jax.device_get(jax.jit(batched, static_argnums=(2, 3))(scenarios, gains, sim, mpc))


def _batch(dtype):
    """The three-obstacle field (cylinder, mover, padded slot) next to four dynamic fields."""
    one = three_obstacle_field(jnp, dtype)
    dynamic = make_scenarios(5, family_params("dynamic", max_obstacles=4), jnp.arange(4))
    dynamic = jax.tree_util.tree_map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x,
                                     dynamic)
    parts = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), (one.start, one.goal, one.obstacles),
                                   (dynamic.start, dynamic.goal, dynamic.obstacles))
    return Scenario(*parts)


@pytest.mark.parametrize("method,convention,sim_kw,mpc_kw", [
    ("basic", "intent", {}, {}),
    ("direction", "literal", {}, {}),
    ("direction_velocity", "intent", {"a_max": 0.8}, {"v_penalty": 5.0}),
    ("direction_velocity", "literal", {"att_cap": 4.0, "reference_velocity": True}, {"q_vel": [0.5, 0.5, 1.0]}),
])
def test_float64_agrees_with_the_engine_to_rounding(method, convention, sim_kw, mpc_kw):
    sim = SimConfig.from_flat(method=method, convention=convention, t_max=4.0, **sim_kw)
    mpc = MPCConfig(horizon=8, iters=25, **mpc_kw)
    with jax.enable_x64(True):
        scenarios = _batch(jnp.float64)
        traj = _engine(scenarios, Gains(**GAINS).as_arrays(jnp.float64), sim, mpc)
        peer = vectorised_rollout(scenarios, Gains(**GAINS), sim, mpc, dtype=np.float64)
    assert peer["position"].shape == (5, sim.episode.steps + 1, 3) and peer["position"].dtype == np.float64
    np.testing.assert_allclose(peer["position"], traj.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(peer["control"], traj.control, rtol=0, atol=1e-8)
    assert np.linalg.norm(peer["position"][:, -1] - peer["position"][:, 0], axis=-1).min() > 1.0  # they moved
    if "a_max" in sim_kw:
        assert np.any(np.abs(peer["control"]) >= sim.vehicle.a_max - 1e-9)  # the box was active


@pytest.mark.slow
def test_float32_agrees_with_the_engine_on_a_short_episode():
    sim, mpc = SimConfig.from_flat(t_max=2.0), MPCConfig(horizon=10, iters=30)
    scenarios = make_scenarios(2, family_params("clutter", max_obstacles=8), jnp.arange(16))
    traj = _engine(scenarios, Gains(), sim, mpc)
    peer = vectorised_rollout(scenarios, Gains(), sim, mpc)
    assert peer["position"].dtype == np.float32
    np.testing.assert_allclose(peer["position"], traj.position, rtol=0, atol=1e-3)


@pytest.mark.parametrize("setting", [{"method": "direction_normalised"}, {"sensor": "noisy"},
                                     {"disturbance": "wind"}, {"estimator": "observer"}])
def test_unknown_components_are_refused(setting):
    """The peer and the oracle fly the paper's ideal world only: any other component is refused, never
    silently replaced by the ideal one."""
    from jaxapf.bench.oracle import oracle_rollout

    (key, value), = setting.items()
    sim = SimConfig.from_flat(**setting)
    with pytest.raises(ConfigError, match=rf"sim\.{key} \(the vectorised numpy peer\) = '{value}'"):
        vectorised_rollout(_batch(jnp.float32), Gains(), sim, MPCConfig())
    pytest.importorskip("osqp")
    with pytest.raises(ConfigError, match=rf"sim\.{key} \(the numpy \+ OSQP oracle\) = '{value}'"):
        oracle_rollout(jax.tree_util.tree_map(lambda x: x[0], _batch(jnp.float32)), Gains(), sim, MPCConfig())


@pytest.mark.slow
def test_bench_times_the_vectorised_peer_and_prints_its_ratio():
    result = run_benchmark(fields=8, obstacles=4, horizon=4, iters=3, steps=6, oracle_fields=0, vectorised_steps=4)
    vec = result["vectorised"]
    assert vec["steps"] == 4 and len(vec["run_all_s"]) == 3
    assert vec["blas_threads"].startswith(("1 (", "not pinned"))
    assert vec["steps_per_s"] == pytest.approx(8 * 4 / vec["run_s"])
    assert result["speedup_vectorised"] == pytest.approx(result["engine"]["steps_per_s"] / vec["steps_per_s"])
    assert "speed-up (engine / vectorised numpy steps/s)" in format_benchmark(result)
    assert run_benchmark(fields=8, obstacles=4, horizon=4, iters=3, steps=6, oracle_fields=0,
                         vectorised_steps=0)["vectorised"] is None


@pytest.mark.parametrize("method", ["basic", "direction", "direction_velocity"])
@pytest.mark.parametrize("convention", ["intent", "literal"])
def test_repulsion_matches_the_oracle_force_inside_and_outside_obstacles(method, convention):
    """The peer's rewritten force (one pass per coefficient) against the oracle's formulas, per field,
    at states scattered through the fields: inside obstacles (the clearance floor), moving obstacles,
    cylinders and padded slots."""
    from jaxapf.bench import vectorised
    from jaxapf.bench.oracle import _attractive, _gain_values, total_force

    sim = SimConfig.from_flat(method=method, convention=convention)
    gains = _gain_values(Gains(**GAINS))
    host = jax.tree_util.tree_map(lambda a: np.repeat(np.asarray(a), 40, axis=0), _batch(jnp.float32))
    field = vectorised._Field(host, gains, sim, np.float64)
    rng = np.random.default_rng(1)
    p = field.start + rng.normal(0, 4, (3, 200))
    v = rng.normal(0, 1.5, (3, 200))
    got = vectorised._repulsion(field, p, v, 1.3)
    obs = host.obstacles
    for i in range(p.shape[1]):
        proj = np.ones((obs.radius.shape[1], 3))
        proj[np.asarray(obs.cylinder[i], bool), 2] = 0.0
        f64 = lambda a, i=i: np.asarray(a[i], np.float64)  # noqa: E731
        arrays = dict(position=f64(obs.position), velocity=f64(obs.velocity), radius=f64(obs.radius),
                      valid=np.asarray(obs.valid[i], bool), proj=proj, goal=f64(host.goal))
        want = -total_force(p[:, i], v[:, i], 1.3, arrays, gains, sim) - _attractive(p[:, i], arrays["goal"],
                                                                                    gains["k_att"], None)[1]
        np.testing.assert_allclose(got[:, i], want, rtol=1e-10, atol=1e-9 * max(1.0, np.abs(want).max()))
    d = np.linalg.norm((p[:, None] - field.pos) * np.stack([np.ones_like(field.pz)] * 2 + [field.pz]), axis=0)
    assert np.any((d - field.reach < sim.planner.d_min) & (field.neg_k < 0))  # some states inside an obstacle


def test_blas_pinning_without_threadpoolctl_reads_the_environment(monkeypatch):
    import sys

    from jaxapf.bench.engine import blas_one_thread

    monkeypatch.setitem(sys.modules, "threadpoolctl", None)  # as if not installed
    for name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    assert blas_one_thread()[1].startswith("not pinned")
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    context, how = blas_one_thread()
    assert how == "1 (OPENBLAS_NUM_THREADS=1)"
    with context:
        pass

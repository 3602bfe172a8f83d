"""The closed loop: exact plant, box, masks, determinism, gain grids in one compiled call."""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import assert_same_episodes

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Obstacles, Scenario
from jaxapf.engine import evaluate, evaluate_program, rollout
from jaxapf.gains import Gains
from jaxapf.metrics import episode_metrics
from jaxapf.planners import PLANNERS
from jaxapf.world import step

SIM = SimConfig.from_flat(t_max=8.0)
MPC = MPCConfig(horizon=8, iters=15)
_rollout = jax.jit(rollout, static_argnames=("sim", "mpc"))


def _scenario(extra_padding: int = 0, decoy: bool = False) -> Scenario:
    """Two real obstacles (a cylinder and a moving sphere) plus padded slots; with ``decoy`` a padded
    slot sits right on the path, so the mask is what keeps it out."""
    pos = [[4.0, 0.3, 2.0], [6.0, -3.0, 2.0]]
    vel = [[0.0, 0.0, 0.0], [0.0, 0.8, 0.0]]
    rad, cyl, valid = [0.8, 0.6], [True, False], [True, True]
    for i in range(extra_padding):
        pos.append([2.0, 0.0, 2.0] if decoy and i == 0 else [1e6, 1e6, 1e6])
        vel.append([0.0, 0.0, 0.0])
        rad.append(0.5 if decoy and i == 0 else 0.0)
        cyl.append(False)
        valid.append(False)
    obs = Obstacles(position=jnp.array(pos), velocity=jnp.array(vel), radius=jnp.array(rad),
                    cylinder=jnp.array(cyl), valid=jnp.array(valid))
    return Scenario(start=jnp.array([0.0, 0.0, 2.0]), goal=jnp.array([8.0, 0.5, 2.0]), obstacles=obs)


@pytest.fixture(scope="module")
def traj():
    return _rollout(_scenario(), Gains(), SIM, MPC)


def test_plant_integrates_the_applied_control_exactly(traj):
    x = jnp.concatenate([traj.position, traj.velocity], axis=1)
    stepped = jax.vmap(step, in_axes=(0, 0, None))(x[:-1], traj.control, SIM.episode.dt)
    np.testing.assert_allclose(stepped, x[1:], rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.time, np.arange(SIM.episode.steps + 1) * SIM.episode.dt, atol=1e-6)
    np.testing.assert_array_equal(traj.position[0], [0.0, 0.0, 2.0])
    np.testing.assert_array_equal(traj.velocity[0], 0.0)


def test_acceleration_box_holds(traj):
    assert float(jnp.abs(traj.control).max()) <= SIM.vehicle.a_max * (1 + 1e-6)
    assert float(jnp.abs(traj.control).max()) > 0.5 * SIM.vehicle.a_max  # the box is actually reached


def test_moves_toward_the_goal(traj):
    goal = np.array([8.0, 0.5, 2.0])
    d = np.linalg.norm(np.asarray(traj.position) - goal, axis=1)
    assert d[-1] < 0.5 * d[0]


def test_same_inputs_same_numbers(traj):
    again = _rollout(_scenario(), Gains(), SIM, MPC)
    for a, b in zip(jax.tree_util.tree_leaves(traj), jax.tree_util.tree_leaves(again)):
        np.testing.assert_array_equal(a, b)


def test_padded_slots_change_nothing_in_the_closed_loop(traj):
    padded = _rollout(_scenario(extra_padding=3, decoy=True), Gains(), SIM, MPC)
    np.testing.assert_array_equal(padded.position, traj.position)
    np.testing.assert_array_equal(padded.control, traj.control)


@pytest.mark.slow
def test_gain_grid_is_one_compiled_call_matching_single_runs():
    scenarios = jax.tree_util.tree_map(lambda *x: jnp.stack(x), _scenario(), _scenario())
    scenarios = Scenario(start=scenarios.start.at[1, 1].set(-1.0), goal=scenarios.goal,
                         obstacles=scenarios.obstacles)
    grid = Gains(gamma=np.array([0.0, 1.0, 2.0]), k=np.array([0.0, 0.5, 1.0]), k_rep=np.full(3, 10.0),
                 d_s=np.array([3.0, 4.0, 5.0]), k_att=np.ones(3), eta=np.full(3, 0.5))
    metrics = evaluate(scenarios, grid, SIM, MPC)
    assert metrics["min_clearance"].shape == (3, 2)
    size = evaluate_program.compiled()
    other = jax.tree_util.tree_map(lambda g: g * 0.9, grid)
    evaluate(scenarios, other, SIM, MPC)
    assert evaluate_program.compiled() == size, "changing gain values must not recompile"
    # entry (g, f) is the single episode with those gains on that field
    for g, f in [(0, 0), (2, 1)]:
        one = jax.tree_util.tree_map(lambda x, g=g: x[g] if np.ndim(x) else x, grid)  # gains left scalar broadcast
        field = jax.tree_util.tree_map(lambda x, f=f: x[f], scenarios)
        single = episode_metrics(_rollout(field, one, SIM, MPC), field, SIM)
        assert_same_episodes({n: np.asarray(metrics[n])[g, f][None] for n in single},
                             {n: np.asarray(v)[None] for n, v in single.items()}, SIM.episode.dt)


@pytest.mark.slow
def test_float64_rollout():
    with jax.enable_x64(True):
        sc = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64) if x.dtype == jnp.float32 else x,
                                    _scenario())
        out = rollout(sc, Gains(), SimConfig.from_flat(t_max=1.0), MPCConfig(horizon=4, iters=5))
        assert out.position.dtype == jnp.float64
        assert np.all(np.isfinite(np.asarray(out.position)))


@pytest.mark.slow
def test_episode_numbers_do_not_depend_on_the_batch():
    """Field f gives bit-identical metrics whether run in a batch of 5 or of 3 (width 2, padded)."""
    fields = [_scenario(), _scenario(), _scenario(), _scenario(), _scenario()]
    fields = [Scenario(start=s.start.at[1].set(0.4 * i), goal=s.goal, obstacles=s.obstacles)
              for i, s in enumerate(fields)]
    stack = lambda xs: jax.tree_util.tree_map(lambda *x: jnp.stack(x), *xs)  # noqa: E731
    grid = jax.tree_util.tree_map(lambda x: jnp.asarray([x, 0.5 * x]), Gains())
    short = SimConfig.from_flat(t_max=2.0)
    five = evaluate(stack(fields), grid, short, MPC, width=2)
    three = evaluate(stack(fields[2:]), grid, short, MPC, width=2)
    for name in five:
        np.testing.assert_array_equal(np.asarray(five[name])[:, 2:], three[name])


@pytest.mark.slow
def test_apf_reference_follows_the_saturated_flow_in_either_obstacle_layout():
    """SPEC 4: p_{i+1} = p_i + Δt·sat(η F(p_i, v_i, t + iΔt)), v_{i+1} = that step's velocity;
    the closed loop hands the reference the field's columns once per episode, a direct caller
    may hand it the field itself: same numbers."""
    from jaxapf.planners import PLANNERS, saturate
    from jaxapf.planners.potentials import total_force

    sim = SimConfig.from_flat(reference_velocity=True)
    planner = PLANNERS.get(sim.planner.method)
    s, g, horizon, t = _scenario(extra_padding=2), Gains().as_arrays(), 5, 0.7
    x = jnp.array([1.0, 0.2, 2.0, 0.4, 0.0, 0.0])
    ref, state = planner.reference(planner.init(s, g, sim, horizon), x, t, s.goal, s.obstacles, g, sim, horizon)
    assert state == ()
    np.testing.assert_array_equal(ref, planner.reference((), x, t, s.goal, s.obstacles.columns(), g, sim, horizon)[0])
    p, v, cfg, dt = x[:3], x[3:], sim.planner, sim.episode.dt
    for i in range(horizon):
        force = total_force(p, v, t + i * dt, s.goal, s.obstacles, g, method=cfg.method, convention=cfg.convention,
                            r_uav=sim.vehicle.r_uav, d_min=cfg.d_min, eps_v=cfg.eps_v, att_cap=cfg.att_cap)
        v = saturate(g.eta * force, sim.vehicle.v_max)
        p = p + dt * v
        np.testing.assert_allclose(ref[i + 1], jnp.concatenate([p, v]), rtol=1e-5, atol=1e-6)
    assert ref.shape == (horizon + 1, 6)
    np.testing.assert_array_equal(ref[0], x)


@pytest.mark.parametrize("method", PLANNERS.names())
def test_a_rollout_reads_only_the_gains_its_planner_declares(method):
    """The contract a sweep's deduplication of identical settings rests on (jaxapf.engine.gains_read):
    changing every gain outside gains_read changes no number; changing one inside does."""
    from jaxapf.engine import gains_read
    from jaxapf.gains import GAINS

    sim = SimConfig.from_flat(method=method, t_max=4.0)
    mpc = MPCConfig(horizon=4, iters=5)
    read = gains_read(sim)
    base = _rollout(_scenario(), Gains(), sim, mpc)
    unread = {n: GAINS.get(n).value * 0.5 + 0.1 for n in GAINS.names() if n not in read}
    same = _rollout(_scenario(), Gains().replace(**unread), sim, mpc)
    np.testing.assert_array_equal(np.asarray(same.position), np.asarray(base.position))
    gain = "k_rep" if "k_rep" in read else PLANNERS.get(method).gains[0].name  # the repulsion, or what stands for it
    moved = _rollout(_scenario(), Gains().replace(**{gain: 3.0 * Gains()[gain]}), sim, mpc)
    assert gain in read and not np.array_equal(np.asarray(moved.position), np.asarray(base.position))


SCALES = {"mpc_pos": 2.0, "mpc_vel": 3.0, "mpc_terminal": 0.5, "mpc_input": 2.0, "mpc_speed": 0.5}


def _scaled(mpc: MPCConfig) -> MPCConfig:
    """``mpc`` with every weight multiplied by its scale in :data:`SCALES`, compiled in."""
    times = lambda w, s: tuple(x * s for x in w)  # noqa: E731
    return MPCConfig(horizon=mpc.horizon, iters=mpc.iters, q_pos=times(mpc.q_pos, 2.0), q_vel=times(mpc.q_vel, 3.0),
                     f_pos=times(mpc.f_pos, 0.5), f_vel=times(mpc.f_vel, 0.5), r=times(mpc.r, 2.0),
                     v_penalty=mpc.v_penalty * 0.5)


def test_traced_mpc_weights_fly_the_static_weights_they_scale():
    """With ``mpc_weights = "gains"`` the weights are the config's times the traced scales: the episode
    equals the one with the scaled weights compiled in (float64, to rounding), and unit scales are the
    static program exactly; the scales are read only in that mode."""
    gains_mode = SIM.replace(mpc_weights="gains")
    with jax.enable_x64(True):
        scenario = jax.tree_util.tree_map(lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x,
                                          _scenario())
        traced = _rollout(scenario, Gains(**SCALES), gains_mode, MPC)
        static = _rollout(scenario, Gains(), SIM, _scaled(MPC))
        np.testing.assert_allclose(traced.position, static.position, rtol=0, atol=1e-9)
        assert float(jnp.abs(traced.position - _rollout(scenario, Gains(), SIM, MPC).position).max()) > 0.1
        unit = _rollout(scenario, Gains(), gains_mode, MPC)
        np.testing.assert_allclose(unit.position, _rollout(scenario, Gains(), SIM, MPC).position, rtol=0, atol=1e-12)
    ignored = _rollout(_scenario(), Gains(**SCALES), SIM, MPC)  # static mode: the scales are not read
    np.testing.assert_array_equal(ignored.position, _rollout(_scenario(), Gains(), SIM, MPC).position)


def test_a_grid_over_mpc_weights_is_one_call_matching_single_runs():
    """``evaluate`` (the streaming engine) over settings that scale the MPC's weights: each row is
    that setting's own rollout."""
    gains_mode = SIM.replace(mpc_weights="gains")
    settings = [Gains(), Gains(mpc_pos=0.5, mpc_input=3.0), Gains(**SCALES)]
    batch = jax.tree_util.tree_map(lambda *x: np.asarray(x, np.float32), *settings)
    scenarios = jax.tree_util.tree_map(lambda x: x[None], _scenario())
    out = evaluate(scenarios, batch, gains_mode, MPC, metrics=("final_distance", "min_clearance"))
    for i, g in enumerate(settings):
        one = episode_metrics(_rollout(_scenario(), g, gains_mode, MPC), _scenario(), gains_mode,
                              ("final_distance", "min_clearance"))
        assert_same_episodes({n: np.asarray(out[n])[i, 0][None] for n in one},
                             {n: np.asarray(v)[None] for n, v in one.items()}, SIM.episode.dt)
    assert len({round(float(v), 3) for v in out["final_distance"][:, 0]}) == 3
    size = evaluate_program.compiled()
    evaluate(scenarios, jax.tree_util.tree_map(lambda g: g * 0.9, batch), gains_mode, MPC,
             metrics=("final_distance", "min_clearance"))
    assert evaluate_program.compiled() == size, "changing the MPC's weights must not recompile"


def test_ideal_tracking_reaches_each_chosen_velocity_within_the_step():
    """``tracking = "ideal"`` (the MPC ablation): after every step the plant's velocity is the one the velocity
    obstacles chose at the step's start (their ``velocity`` evaluated independently there, the moving sphere
    included), the position the exact integral of that one-step ramp, and the acceleration can exceed the
    box (no MPC); with the MPC the box holds and the velocity lags."""
    sim = SimConfig.from_flat(method="velocity_obstacle", tracking="ideal", t_max=8.0)
    scenario = _scenario()
    traj = _rollout(scenario, Gains(), sim, MPC)
    planner, gains = PLANNERS.get("velocity_obstacle"), Gains().as_arrays(jnp.float32)
    obstacles = scenario.obstacles.columns()
    dt = sim.episode.dt
    for k in range(0, 80, 7):
        x = jnp.concatenate([traj.position[k], traj.velocity[k]])
        chosen = planner.velocity(x, k * dt, scenario.goal, obstacles, gains, sim)[0]
        np.testing.assert_allclose(traj.velocity[k + 1], chosen, atol=2e-5)
        np.testing.assert_allclose(traj.position[k + 1], traj.position[k] + 0.5 * dt * (traj.velocity[k] + chosen),
                                   atol=2e-5)
    assert float(jnp.max(jnp.abs(traj.control))) > sim.vehicle.a_max  # the first step alone needs more
    tracked = _rollout(scenario, Gains(), sim.replace(tracking="mpc"), MPC)
    assert float(jnp.max(jnp.abs(tracked.control))) <= sim.vehicle.a_max + 1e-6
    assert float(jnp.abs(tracked.velocity[1] - traj.velocity[1]).max()) > 0.1


def test_ideal_tracking_refuses_an_estimator():
    with pytest.raises(Exception, match="sim.estimator must be 'none'"):
        SimConfig.from_flat(tracking="ideal", estimator="observer")


def test_compiled_programs_are_bounded_and_their_memory_maps_freed(monkeypatch):
    """Past MAX_PROGRAMS live programs a call empties every program's cache first, so a process compiling
    hundreds of them keeps a bounded number of memory maps (Linux allows 65,530); a program called again
    compiles again and gives the same numbers."""
    import jaxapf.engine.batch as batch

    def maps():  # 0 where the system does not list them
        if not pathlib.Path("/proc/self/maps").exists():
            return 0
        with open("/proc/self/maps") as fh:
            return sum(1 for _ in fh)

    @batch.program(static_argnames="n")
    def f(x, n):
        for i in range(n):  # n kernels' worth of distinct work
            x = jnp.sin(x * (i + 1)) + jnp.cumsum(x)
        return x

    monkeypatch.setattr(batch, "MAX_PROGRAMS", 3)
    for j in batch._JITTED:
        j.clear_cache()
    x = jnp.linspace(0.0, 1.0, 8)
    first = np.asarray(f(x, 1))
    peak = 0
    for n in range(2, 12):
        f(x, n).block_until_ready()
        assert sum(j._cache_size() for j in batch._JITTED) <= 3
        peak = max(peak, maps())
    assert f.compiled() == 11
    np.testing.assert_array_equal(np.asarray(f(x, 1)), first)
    assert f.compiled() == 12  # cleared since: compiled again
    if maps():
        unbounded = maps()
        monkeypatch.setattr(batch, "MAX_PROGRAMS", 1000)
        for n in range(12, 22):
            f(x, n).block_until_ready()
        assert maps() > unbounded and peak < maps()


def test_docs_state_the_bound_on_compiled_programs():
    from conftest import ROOT

    from jaxapf.engine.batch import MAX_PROGRAMS

    assert f"keeps at most {MAX_PROGRAMS}\n  programs compiled" in (ROOT / "docs" / "sweep.md").read_text()

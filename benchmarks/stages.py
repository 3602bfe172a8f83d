"""Where a scenario-step's time goes, stage by stage, against what the machine can do.

    python benchmarks/stages.py [--fields 1024] [--json]

The standard case (``clutter``, 16 obstacle slots, N = 20, 30 FISTA iterations, ``direction_velocity``,
the double integrator) is flown 50 steps by the engine's own control step to a mid-flight batch of
states; then each stage of that step (:func:`jaxapf.engine.loop.loop_step`) is compiled alone, vmapped over
the fields, compiled as the engine's programs are (:func:`jaxapf.engine.program`: the same XLA options), and
timed on that batch (the median of ``--repeats`` calls): the sensor, the planner's
reference (the potential field rolled N steps ahead), the MPC with one FISTA iteration (its set-up: the
condensed QP's linear term, the warm start, one iteration), each further FISTA iteration (the 30-iteration
solve minus the one-iteration one, per iteration), the plant, the whole control step, and the engine's
step (``evaluate`` over whole episodes, per scenario-step: the loop plus metrics and the streaming
engine's bookkeeping). Each stage's FLOPs are counted on its jaxpr (:func:`count_flops`: a matrix
product ``2mnk``, an elementwise or reducing operation one per element, a transcendental function one
per element too (listed apart), a ``scan`` its body times its length; XLA's ``cost_analysis`` counts a
loop's body once, so it cannot be used here), so each stage's achieved rate and its time at the
machine's peak follow. The peak is measured, not quoted: a
float32 matrix product large enough to keep every core's FMA units busy (``--peak-size``).
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxapf.bench.engine import bench_case, environment


def _median_time(fn, args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


#: Primitives that move or select data without arithmetic.
_FREE = {"broadcast_in_dim", "reshape", "squeeze", "expand_dims", "transpose", "slice", "dynamic_slice",
         "dynamic_update_slice", "concatenate", "gather", "scatter", "select_n", "convert_element_type", "iota",
         "copy", "copy_p", "pad", "rev", "stop_gradient", "eq", "ne", "lt", "le", "gt", "ge", "and", "or", "not",
         "xor", "sort", "argmax", "argmin", "clamp", "sign", "floor", "ceil", "round", "is_finite", "device_put",
         "random_bits", "random_seed", "random_wrap", "random_unwrap", "threefry2x32", "shift_right_logical",
         "shift_left", "bitcast_convert_type", "population_count", "split"}
_TRANSCENDENTAL = {"exp", "exp2", "log", "log1p", "expm1", "sqrt", "rsqrt", "cbrt", "sin", "cos", "tan", "tanh",
                   "atan2", "asin", "acos", "atan", "pow", "logistic", "erf", "erf_inv", "sinh", "cosh"}


def count_flops(jaxpr) -> dict[str, float]:
    """Arithmetic of a (closed) jaxpr: ``{"flops": …, "transcendental": …}`` (module docstring); a
    ``while`` loop of unknown trip count is counted once and reported in ``"while_loops"``."""
    total = {"flops": 0.0, "transcendental": 0.0, "while_loops": 0.0}

    def add(counts, times=1.0):
        for key, value in counts.items():
            total[key] += times * value

    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        size = float(sum(np.prod(v.aval.shape) for v in eqn.outvars if hasattr(v.aval, "shape")))
        subs = {k: v for k, v in eqn.params.items() if hasattr(v, "eqns") or hasattr(v, "jaxpr")}
        if name == "scan":
            add(count_flops(eqn.params["jaxpr"].jaxpr), eqn.params["length"])
        elif name == "while":
            add(count_flops(eqn.params["body_jaxpr"].jaxpr))
            total["while_loops"] += 1
        elif name == "cond":
            branches = [count_flops(b.jaxpr) for b in eqn.params["branches"]]
            add(max(branches, key=lambda c: c["flops"]))
        elif subs:  # pjit, custom_jvp_call, custom_vjp_call, remat, closed_call: their body once
            for sub in subs.values():
                add(count_flops(getattr(sub, "jaxpr", sub)))
        elif name == "dot_general":
            (contract, _), _ = eqn.params["dimension_numbers"]
            lhs = eqn.invars[0].aval.shape
            total["flops"] += 2.0 * size * float(np.prod([lhs[d] for d in contract]))
        elif name in ("reduce_sum", "reduce_max", "reduce_min", "reduce_prod", "argmax", "cumsum", "cumprod",
                      "cummax", "cumlogsumexp"):
            total["flops"] += float(np.prod(eqn.invars[0].aval.shape))
        elif name in _TRANSCENDENTAL:
            total["transcendental"] += size
            total["flops"] += size
        elif name not in _FREE:
            total["flops"] += size
    return total


def _flops(fn, args) -> dict[str, float]:
    return count_flops(jax.make_jaxpr(fn)(*args).jaxpr)


def peak_gflops(size: int, repeats: int) -> float:
    """The float32 rate of a ``size``² matrix product on every core: the machine's practical FMA peak."""
    a = jnp.ones((size, size), jnp.float32)
    fn = jax.jit(lambda x: x @ x)
    return 2 * size**3 / _median_time(fn, (a,), repeats) / 1e9


def stage_profile(fields: int = 1024, repeats: int = 20, warm_steps: int = 50, peak_size: int = 2048) -> dict:
    from jaxapf.control import solve_axes
    from jaxapf.engine import program
    from jaxapf.engine.loop import closed_loop, episode_loop, loop_init, loop_step

    case = bench_case(fields, 16, 20, 30, 300, "clutter", width=fields)
    sim, mpc, scenarios = case["sim"], case["mpc"], case["scenarios"]
    gains = case["gains"]
    dtype = scenarios.start.dtype
    loop = episode_loop(closed_loop(sim, mpc, dtype), gains, sim, mpc, dtype)

    def one_step(carry, k, s):
        return loop_step(loop, carry, k, s, s.obstacles.columns(), gains, sim, mpc)[0]

    carry = jax.vmap(lambda s: loop_init(loop, s, gains, sim, mpc))(scenarios)
    advance = program(jax.vmap(lambda c, s: jax.lax.fori_loop(0, warm_steps, lambda i, c: one_step(
        c, jnp.asarray(i, dtype), s), c)))
    carry = jax.block_until_ready(advance(carry, scenarios))
    k = jnp.asarray(warm_steps, dtype)
    t = k * sim.episode.dt
    state, warm = carry[0], carry[1]

    def sensor(c, s):
        return loop.sensor(c[4], loop.plant.kinematics(c[0]), jnp.round(k).astype(jnp.int32), s,
                           s.obstacles.columns(), gains, sim)[:2]

    def reference(c, s):
        x = loop.plant.kinematics(c[0])
        return loop.planner.reference(c[2], x, t, s.goal, s.obstacles.columns(), gains, sim, mpc.horizon)[0]

    x_ref = program(jax.vmap(reference))(carry, scenarios)
    xs = jax.vmap(loop.plant.kinematics)(state)

    def mpc_solve(iters):
        def run(x, r, w):
            return solve_axes(loop.prob, x, r, w, a_max=sim.vehicle.a_max, v_max=sim.vehicle.v_max, iters=iters)
        return run

    def plant(st, a):
        return loop.plant.step(st, a, jnp.zeros(3, dtype), gains, sim)[0]

    accel = jnp.zeros((fields, 3), dtype)
    stages = {
        "sensor": (jax.vmap(sensor), (carry, scenarios)),
        "reference": (jax.vmap(reference), (carry, scenarios)),
        "mpc_one_iteration": (jax.vmap(mpc_solve(1)), (xs, x_ref, warm)),
        "mpc_all_iterations": (jax.vmap(mpc_solve(mpc.iters)), (xs, x_ref, warm)),
        "plant": (jax.vmap(plant), (state, accel)),
        "control_step": (jax.vmap(lambda c, s: one_step(c, k, s)), (carry, scenarios)),
    }
    out = {}
    for name, (fn, args) in stages.items():
        seconds = _median_time(program(fn), args, repeats)
        counted = _flops(fn, args)
        out[name] = {"us_per_scenario_step": 1e6 * seconds / fields,
                     "flops_per_scenario_step": counted["flops"] / fields,
                     "transcendental_per_scenario_step": counted["transcendental"] / fields,
                     "uncounted_while_loops": counted["while_loops"]}
    one, full = out["mpc_one_iteration"], out["mpc_all_iterations"]
    out["fista_iteration"] = {key: (full[key] - one[key]) / (mpc.iters - 1) for key in (
        "us_per_scenario_step", "flops_per_scenario_step", "transcendental_per_scenario_step")}
    # the engine's own step: whole episodes through evaluate (streaming, with the metrics), per scenario-step
    from jaxapf.bench.engine import lower_case

    compiled, args = lower_case(case)
    compiled = compiled.compile()
    engine_s = _median_time(compiled, args, max(3, repeats // 5))
    out["engine_step"] = {"us_per_scenario_step": 1e6 * engine_s / (fields * sim.episode.steps),
                          "flops_per_scenario_step": None}
    peak = peak_gflops(peak_size, max(3, repeats // 5))
    for row in out.values():
        f = row["flops_per_scenario_step"]
        row["gflops"] = None if f is None else f / row["us_per_scenario_step"] / 1e3
        row["share_of_peak"] = None if f is None else row["gflops"] / peak
        row["us_at_peak"] = None if f is None else f / peak / 1e3
    return {"config": {"fields": fields, "obstacles": 16, "horizon": mpc.horizon, "iters": mpc.iters,
                       "family": "clutter", "method": sim.planner.method, "warm_steps": warm_steps,
                       "repeats": repeats, "peak_size": peak_size},
            "environment": environment(dtype), "peak_gflops": peak, "stages": out,
            "engine_steps_per_us": 1.0 / out["engine_step"]["us_per_scenario_step"]}


def format_profile(result: dict) -> str:
    lines = [f"peak (float32 {result['config']['peak_size']}² matmul): {result['peak_gflops']:.1f} GFLOP/s",
             f"{'stage':<20} {'µs/step':>9} {'kFLOP/step':>11} {'GFLOP/s':>8} {'of peak':>8} {'µs at peak':>11}"]
    for name, row in result["stages"].items():
        f = row["flops_per_scenario_step"]
        lines.append(f"{name:<20} {row['us_per_scenario_step']:>9.3f} "
                     + (f"{f / 1e3:>11.1f} {row['gflops']:>8.2f} {100 * row['share_of_peak']:>7.1f}% "
                        f"{row['us_at_peak']:>11.3f}" if f is not None else f"{'–':>11} {'–':>8} {'–':>8} {'–':>11}"))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fields", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--peak-size", type=int, default=2048)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    result = stage_profile(args.fields, args.repeats, peak_size=args.peak_size)
    print(json.dumps(result, indent=1) if args.json else format_profile(result))


if __name__ == "__main__":
    main()

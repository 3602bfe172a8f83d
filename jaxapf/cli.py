"""The ``jaxapf`` command line: ``simulate``, ``bench``, ``tune``, ``sweep`` and ``report``.

Configuration errors are reported as one line naming the field and its allowed range, with exit
status 2; nothing reaches the user as a traceback from inside JAX.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time
from typing import Sequence

from .config import METHODS, CONVENTIONS, ConfigError, Gains, MPCConfig, SimConfig, check_int, gains_from_mapping, load_gains

__all__ = ["main", "build_parser"]

_GAIN_FLAGS = {"gamma": "γ", "k": "k", "k_rep": "k_rep", "d_s": "d_s [m]", "k_att": "k_att", "eta": "η"}


def _methods(text: str) -> list[str]:
    methods = [m.strip() for m in text.split(",") if m.strip()]
    for m in methods:
        if m not in METHODS:
            raise argparse.ArgumentTypeError(f"unknown method {m!r}; choose from {', '.join(METHODS)}")
    if not methods:
        raise argparse.ArgumentTypeError("give at least one method")
    return methods


def _add_planner_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("planner gains (defaults: jaxapf.config.Gains)")
    g.add_argument("--gains", type=pathlib.Path, metavar="FILE",
                   help="TOML file with gain values ([gains] table or top-level keys)")
    for name, label in _GAIN_FLAGS.items():
        g.add_argument(f"--{name.replace('_', '-')}", dest=name, type=float, metavar="X",
                       help=f"gain {label}")
    s = p.add_argument_group("simulation and MPC")
    s.add_argument("--convention", choices=CONVENTIONS, default="intent")
    s.add_argument("--dt", type=float, default=0.1, help="control step [s] (default 0.1)")
    s.add_argument("--t-max", type=float, help="episode length [s] (default: the family's)")
    s.add_argument("--horizon", type=int, default=MPCConfig.horizon, help="MPC horizon N")
    s.add_argument("--iters", type=int, default=MPCConfig.iters, help="FISTA iterations per step")
    s.add_argument("--x64", action="store_true", help="run in float64")


def _gains(args: argparse.Namespace) -> Gains:
    base = load_gains(args.gains) if args.gains else Gains()
    given = {n: getattr(args, n) for n in _GAIN_FLAGS if getattr(args, n) is not None}
    return gains_from_mapping(given, where="--", base=base) if given else base


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxapf", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    sim = sub.add_parser("simulate", help="one field, several methods side by side, figures and trajectories")
    sim.add_argument("--family", default="paper_static",
                     help="scenario family (paper_static, paper_dynamic, trap, clutter, crossing, head_on, "
                          "overtake, dynamic); default paper_static")
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--field", type=int, default=0, help="field index within the seed")
    sim.add_argument("--methods", type=_methods, default=["basic", "direction_velocity"],
                     help="comma-separated methods (default basic,direction_velocity)")
    sim.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/simulate"),
                     help="output folder (default out/simulate)")
    _add_planner_flags(sim)

    bench = sub.add_parser("bench", help="engine throughput vs a numpy+OSQP loop")
    bench.add_argument("--fields", type=int, default=1024)
    bench.add_argument("--obstacles", type=int, default=16)
    bench.add_argument("--horizon", type=int, default=20)
    bench.add_argument("--iters", type=int, default=30)
    bench.add_argument("--steps", type=int, help="control steps per episode (default 300; 100 with --split)")
    bench.add_argument("--baseline-fields", type=int, default=3,
                       help="fields run by the numpy+OSQP loop (0: skip the baseline)")
    bench.add_argument("--family", default="clutter")
    bench.add_argument("--chunk", type=int, help="episodes per vmapped chunk (default: 1024 on CPU, 4096 on accelerators)")
    bench.add_argument("--devices", type=int, default=1,
                       help="split the fields over N devices (on CPU the host is split into N devices, as "
                            "`jaxapf sweep` does; default 1)")
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    bench.add_argument("--sweep", nargs="?", const="", type=str, metavar="SPEC",
                       help="instead: end-to-end sweep throughput vs bare evaluate, and the speed-up on 2 CPU "
                            "devices (SPEC: a sweep spec TOML; default a built-in 2,048-episode study)")
    bench.add_argument("--fit-cost", action="store_true",
                       help="instead: fit the per-step cost model behind `jaxapf sweep --dry-run` on this machine")
    bench.add_argument("--split", action="store_true",
                       help="instead: where a step's time goes (all obstacle slots and iterations, one obstacle, "
                            "one iteration, both; --steps defaults to 100), timed interleaved")
    bench.add_argument("--kernels", action="store_true",
                       help="instead: picoseconds per element of single elementwise ops (multiply-add, sqrt, "
                            "divide, tanh) on --fields x --obstacles arrays and transposed, compiled with the "
                            "shipped XLA options and with XLA's fusion emitters")
    bench.add_argument("--xla-option", action="append", metavar="KEY=VALUE",
                       help="instead: time the engine compiled with rollout.XLA_OPTIONS against the same with "
                            "KEY=VALUE (repeatable), one lowering, runs interleaved, e.g. "
                            "--xla-option xla_cpu_use_fusion_emitters=true")

    tune = sub.add_parser("tune", help="learn the planner gains by gradient descent through the closed loop "
                                       "and test them against defaults, grid and random search")
    tune.add_argument("spec", type=pathlib.Path, help="tune spec TOML (see docs/tune.md)")
    tune.add_argument("--out", type=pathlib.Path,
                      help="output folder (default runs/tune-NAME); a checkpoint there is resumed")
    tune.add_argument("--quiet", action="store_true", help="no progress bar or messages")

    rep = sub.add_parser("report", help="statistics, figures and tables (HTML, Markdown, CSV, LaTeX) from a "
                                        "sweep's episodes (see docs/report.md)")
    rep.add_argument("sweep", type=pathlib.Path, help="the sweep's output, runs/NAME.parquet")
    rep.add_argument("--out", type=pathlib.Path, help="output folder (default reports/NAME/)")
    rep.add_argument("--baseline", default="method=basic", metavar="COLUMN=VALUE[,...]",
                     help="baseline setting(s) every other setting is compared with (default method=basic; "
                          "e.g. setting=3 or method=direction,convention=intent)")
    rep.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE[,VALUE]",
                     help="keep only these rows, e.g. family=trap or method=direction_velocity (repeatable; "
                          "values of one flag are OR-ed, flags AND-ed)")
    rep.add_argument("--heatmap", default="gamma,k", metavar="X,Y",
                     help="the two swept gains of the heatmaps (default gamma,k; 'none' to skip)")
    rep.add_argument("--gallery", type=int, default=3, metavar="N",
                     help="worst episodes re-simulated and drawn (default 3; 0 to skip)")
    rep.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples (default 2000)")
    rep.add_argument("--confidence", type=float, default=0.95, help="interval level (default 0.95)")
    rep.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    rep.add_argument("--profile-metric", default="score",
                     help="metric of the performance profile, higher is better (default score)")
    _add_sweep_parser(sub)
    return parser


def _add_sweep_parser(sub: argparse._SubParsersAction) -> None:
    sw = sub.add_parser("sweep", help="run a study stated in a TOML spec into a Parquet dataset (see docs/sweep.md)")
    sw.add_argument("spec", type=pathlib.Path, help="sweep spec TOML, e.g. sweeps/compare-small.toml")
    sw.add_argument("--out", type=pathlib.Path, help="output dataset directory (default runs/NAME.parquet)")
    sw.add_argument("--dry-run", action="store_true",
                    help="print settings, episodes, compiled variants, chunks, time and memory estimates; run nothing")
    sw.add_argument("--gains", type=pathlib.Path, metavar="FILE",
                    help="TOML of gains (e.g. a tuning result) overriding the spec's [gains]")
    sw.add_argument("--overwrite", action="store_true", help="replace the parts of a different (or the same) sweep in --out")
    sw.add_argument("--memory-budget", default="256M", metavar="SIZE",
                    help="working-set budget of one chunk, e.g. 256M, 2G (default 256M)")
    sw.add_argument("--chunk-fields", type=int, metavar="N", help="fields per chunk (default: from the memory budget)")
    sw.add_argument("--devices", type=int, metavar="N",
                    help="on CPU, split the host into N JAX devices (default 1: XLA already spreads the "
                         "engine's wide kernels over the cores)")
    sw.add_argument("--cache-dir", type=pathlib.Path, metavar="DIR",
                    help="persistent XLA compilation cache (default ~/.cache/jaxapf/xla)")
    sw.add_argument("--no-cache", action="store_true", help="no persistent compilation cache")
    sw.add_argument("--distributed", action="store_true",
                    help="jax.distributed.initialize(); each process runs and writes its own chunks "
                         "(the cluster is detected on Slurm, Open MPI and TPU pods; elsewhere give the next three)")
    sw.add_argument("--coordinator", metavar="HOST:PORT", help="with --distributed: address of process 0")
    sw.add_argument("--num-processes", type=int, metavar="N", help="with --distributed: number of processes")
    sw.add_argument("--process-id", type=int, metavar="I", help="with --distributed: this process, 0 … N-1")
    sw.add_argument("--quiet", action="store_true", help="no progress bar")
    sw.add_argument("--x64", action="store_true", help="run in float64")


def _simulate(args: argparse.Namespace) -> int:
    if args.x64:
        import jax

        jax.config.update("jax_enable_x64", True)
    from .scenarios import family_params
    from .simulate import format_metrics_table, simulate_runs, write_outputs

    gains = _gains(args)
    t_max = args.t_max if args.t_max is not None else family_params(args.family).t_max
    sim = SimConfig(method=args.methods[0], convention=args.convention, dt=args.dt, t_max=t_max)
    mpc = MPCConfig(horizon=args.horizon, iters=args.iters)
    start = time.perf_counter()
    field, runs, table = simulate_runs(args.family, args.seed, args.field, args.methods, gains, sim, mpc)
    config = {"command": "simulate", "family": args.family, "seed": args.seed, "field_index": args.field,
              "methods": args.methods, "gains": {n: float(getattr(gains, n)) for n in Gains.names()},
              "sim": vars(sim) | {"method": None}, "mpc": vars(mpc)}
    paths = write_outputs(args.out, field, runs, table, config)
    print(f"{field.title}: {sim.steps} steps of {sim.dt:g} s, {len(runs)} methods "
          f"in {time.perf_counter() - start:.1f} s")
    print(format_metrics_table(runs))
    print(f"wrote {len(paths)} files to {args.out}/:", ", ".join(p.name for p in paths))
    return 0


def _bench(args: argparse.Namespace) -> int:
    from .bench import (compare_xla_options, cost_split, fit_step_cost, format_benchmark, format_cost_split,
                        format_kernel_cost, format_step_cost, format_sweep_benchmark, format_xla_options,
                        kernel_cost, parse_xla_option, run_benchmark, run_sweep_benchmark)

    if args.fit_cost:
        result = fit_step_cost()
        print(json.dumps(result, indent=2) if args.json else format_step_cost(result))
        return 0
    if args.kernels:
        result = kernel_cost(fields=args.fields, obstacles=args.obstacles)
        print(json.dumps(result, indent=2) if args.json else format_kernel_cost(result))
        return 0
    steps = args.steps if args.steps is not None else 100 if args.split else 300
    if args.split:
        result = cost_split(fields=args.fields, obstacles=args.obstacles, horizon=args.horizon, iters=args.iters,
                            steps=steps, family=args.family, chunk=args.chunk)
        print(json.dumps(result, indent=2) if args.json else format_cost_split(result))
        return 0
    if args.xla_option:
        result = compare_xla_options(dict(parse_xla_option(o) for o in args.xla_option), fields=args.fields,
                                     obstacles=args.obstacles, horizon=args.horizon, iters=args.iters,
                                     steps=steps, family=args.family, chunk=args.chunk)
        print(json.dumps(result, indent=2) if args.json else format_xla_options(result))
        return 0
    if args.sweep is not None:
        from .sweep_spec import read_toml

        result = run_sweep_benchmark(read_toml(args.sweep) if args.sweep else None)
        print(json.dumps(result, indent=2) if args.json else format_sweep_benchmark(result))
        return 0

    if args.devices != 1:
        from .sweep import configure_jax

        check_int("bench.devices", args.devices, 1)
        configure_jax(cpu_devices=args.devices)
    result = run_benchmark(fields=args.fields, obstacles=args.obstacles, horizon=args.horizon,
                           iters=args.iters, steps=steps, baseline_fields=args.baseline_fields,
                           family=args.family, chunk=args.chunk, devices=args.devices)
    print(json.dumps(result, indent=2) if args.json else format_benchmark(result))
    return 0


def _tune(args: argparse.Namespace) -> int:
    from .tune import run_tune
    from .tune_train import TuneError

    try:
        run_tune(args.spec, args.out, quiet=args.quiet)
    except TuneError as err:
        print(f"jaxapf tune: error: {err}", file=sys.stderr)
        return 1
    return 0


def _report(args: argparse.Namespace) -> int:
    from .report import ReportOptions, build_report

    heatmap = None if args.heatmap.strip().lower() in ("", "none") else tuple(
        c.strip() for c in args.heatmap.split(","))
    options = ReportOptions(baseline=args.baseline, where=tuple(args.where), heatmap=heatmap,
                            gallery=args.gallery, resamples=args.resamples, confidence=args.confidence,
                            seed=args.seed, profile_metric=args.profile_metric)
    name = args.sweep.name.removesuffix(".parquet") or "report"
    out = args.out if args.out is not None else pathlib.Path("reports") / name
    start = time.perf_counter()
    result = build_report(args.sweep, out, options)
    print(f"report of {args.sweep}: {len(result.summary)} setting × family rows, "
          f"{len(result.comparisons)} paired comparisons in {time.perf_counter() - start:.1f} s")
    for note in result.notes:
        print(f"note: {note}")
    print(f"wrote {out}/report.html, report.md, summary.csv, comparisons.csv, table.tex and "
          f"{sum(1 for p in result.paths if p.parent.name == 'figures')} figure files")
    return 0


def _sweep(args: argparse.Namespace) -> int:
    import warnings

    from .sweep import configure_jax, default_cache_dir, dry_run, parse_size, run_sweep
    from .sweep_spec import load_spec

    budget = parse_size(args.memory_budget)
    cluster = {k: v for k, v in (("coordinator_address", args.coordinator), ("num_processes", args.num_processes),
                                 ("process_id", args.process_id)) if v is not None}
    if cluster and not args.distributed:
        raise ConfigError("--coordinator, --num-processes and --process-id need --distributed")
    if args.num_processes is not None:
        check_int("--num-processes", args.num_processes, 1)
        if args.process_id is not None and not 0 <= args.process_id < args.num_processes:
            raise ConfigError(f"--process-id = {args.process_id} is out of range; allowed: 0 … {args.num_processes - 1}")
    configure_jax(x64=args.x64, cache_dir=None if args.no_cache else args.cache_dir or default_cache_dir(),
                  cpu_devices=args.devices or 1, distributed=args.distributed,
                  cluster=cluster)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        spec = load_spec(args.spec, args.gains)
    for w in caught:
        print(f"jaxapf sweep: warning: {w.message}", file=sys.stderr)
    out = args.out or pathlib.Path("runs") / f"{spec.name}.parquet"
    if args.dry_run:
        print(dry_run(spec, out, overwrite=args.overwrite, memory_budget=budget, chunk_fields=args.chunk_fields))
        return 0
    result = run_sweep(spec, out, memory_budget=budget, chunk_fields=args.chunk_fields, overwrite=args.overwrite,
                       quiet=args.quiet)
    print(result.summary(spec.name))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return {"simulate": _simulate, "bench": _bench, "tune": _tune, "report": _report, "sweep": _sweep}[args.command](args)
    except ConfigError as err:
        print(f"jaxapf {args.command}: error: {err}", file=sys.stderr)
        return 2
    except ImportError as err:
        print(f"jaxapf {args.command}: error: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader went away (`jaxapf ... | head`): stop quietly, as Python's docs advise
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

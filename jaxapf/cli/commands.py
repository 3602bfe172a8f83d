"""The jaxapf command line: simulate, sweep, report, tune, compare, bench and list.

Choices, gain flags and their help texts come from the registries (planners, filters, plants, sensors, disturbances,
estimators, families, metrics, gains), so a registered component appears here with no edit. Configuration
errors are reported as one line naming the field and its allowed range, with exit status 2.

Help, ``list`` and argument errors import no JAX: they read the registries' catalogue
(:mod:`jaxapf.cli.catalog`); a command imports the engine when it runs.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import pathlib
import sys
import threading
import time
from typing import Any, Sequence

from ..text import InertLines, inert

__all__ = ["main", "build_parser"]

#: The registries' catalogue the parser is built from (:func:`jaxapf.cli.catalog.catalog`); set by :func:`main`.
_CATALOG: dict | None = None
#: What an interrupted command leaves behind, for the one line Ctrl-C prints.
_KEPT = {
    "simulate": "no output was written (the files are written after the runs)",
    "sweep": "every finished part is kept; rerun the same command to resume",
    "report": "the report folder may be incomplete; rerun the same command to rewrite it",
    "tune": "the last checkpoint is kept; rerun the same command to resume",
    "compare": "finished selections and test parts are kept; rerun the same command to resume",
    "scorecard": "finished selections and test parts are kept; rerun the same command to resume",
    "bench": "nothing was written",
    "list": "nothing was written",
    "sweep-verify": "nothing was written",
    "sweep-merge": "every part copied so far is complete (copied atomically); rerun the same command to finish",
}


def _catalog() -> dict:
    if _CATALOG is not None:
        return _CATALOG
    from .catalog import catalog

    return catalog(fresh="jaxapf.engine.components" in sys.modules)


def _names(what: str) -> tuple[str, ...]:
    from .catalog import names

    return names(_catalog(), what)


def _planners(text: str) -> list[str]:
    """An argparse type: comma-separated registered planners."""
    planners = _names("planners")
    names = [m.strip() for m in text.split(",") if m.strip()]
    for name in names:
        if name not in planners:
            raise argparse.ArgumentTypeError(f"unknown planner {name!r}; choose from {', '.join(planners)}")
    if not names:
        raise argparse.ArgumentTypeError("give at least one planner")
    return names


def _gain_flags(p: argparse.ArgumentParser) -> None:
    """``--gains FILE`` and one ``--NAME`` flag per declared gain (help from its declaration)."""
    g = p.add_argument_group("gains (default: each gain's declared default; `jaxapf list gains`)")
    g.add_argument("--gains", type=pathlib.Path, metavar="FILE",
                   help="TOML file of gain values (a [gains] table or keys at the top level)")
    for spec in _catalog()["gains"]:
        name = spec["name"]
        unit = f" [{spec['unit']}]" if spec["unit"] else ""
        g.add_argument(f"--{name.replace('_', '-')}", dest=f"gain_{name}", type=float, metavar="X",
                       help=f"{spec['doc']}{unit}; default {spec['default']:g}")


def _gains(args: argparse.Namespace):
    from ..gains import Gains, gains_from_mapping, load_gains

    base = load_gains(args.gains) if args.gains else Gains()
    flagged = (spec["name"] for spec in _catalog()["gains"])
    given = {n: getattr(args, f"gain_{n}") for n in flagged if getattr(args, f"gain_{n}") is not None}
    return gains_from_mapping(given, where="--", base=base) if given else base


def _version() -> str:
    """The installed package's version (its metadata; no import of the package's heavy parts)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("jaxapf")
    except PackageNotFoundError:
        return "(not installed)"


# long: one argparse declaration per command and flag, read top to bottom as the command line's reference
def build_parser() -> argparse.ArgumentParser:
    """The command line's parser, from the registries' catalogue (no JAX import)."""
    cat = _catalog()
    families, planners = _names("families"), _names("planners")

    parser = argparse.ArgumentParser(prog="jaxapf", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"jaxapf {_version()}")
    parser.add_argument("--plugin", action="append", default=[], metavar="MODULE",
                        help="import a module (or .py file) that registers components before the command runs "
                             "(repeatable; docs/extending.md)")
    # `jaxapf sweep verify|merge` are the parsers sweep-verify and sweep-merge: help names them as users type them
    sub = parser.add_subparsers(dest="command", required=True,
                                metavar="{simulate,sweep,sweep verify,sweep merge,report,tune,compare,scorecard,bench,"
                                        "list}")

    sim = sub.add_parser("simulate", help="one field, several planners side by side, figures and trajectories",
                         description="Run planners on one field and write trajectories, metrics and the paper's "
                                     "figures.")
    swarms = _names("swarm-families")
    sim.add_argument("--family", default="paper_static", choices=families + swarms, metavar="NAME",
                     help=f"scenario family: {', '.join(families)} (default paper_static); or a swarm family, "
                          f"{', '.join(swarms)}, whose UAVs all fly each planner")
    sim.add_argument("--agents", type=int, metavar="A",
                     help="UAVs of a swarm family's field (default: the family's)")
    sim.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    sim.add_argument("--field", type=int, help="field index within the seed (default: the first field of the "
                                               "family's defining kind, e.g. trap's concave cup; 0 for a family of "
                                               "one kind)")
    sim.add_argument("--methods", type=_planners, default=["basic", "direction_velocity"],
                     help=f"comma-separated planners of {', '.join(planners)} "
                          "(default basic,direction_velocity)")
    sim.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/simulate"),
                     help="output folder (default out/simulate)")
    sim.add_argument("--animate", action="store_true",
                     help="also write episode.mp4 and episode.gif: the methods' episodes side by side, obstacles "
                          "moving (needs the video extra: pip install -e \".[video]\")")
    _gain_flags(sim)
    s = sim.add_argument_group("simulation and MPC")
    defaults = cat["defaults"]
    for component in cat["components"]:  # every component but the planner (--methods): --filter, --plant, ...
        if component["key"] != "method":
            s.add_argument(f"--{component['key']}", default=component["default"], choices=_names(component["list"]),
                           help=f"{component['role']} (default {component['default']})")
    s.add_argument("--convention", choices=cat["conventions"], default=defaults["convention"],
                   help="sign convention of the direction and velocity weights (default intent)")
    s.add_argument("--dt", type=float, default=defaults["dt"], help=f"control step [s] (default {defaults['dt']:g})")
    s.add_argument("--t-max", type=float, help="episode length [s] (default: the family's)")
    s.add_argument("--horizon", type=int, default=cat["mpc"]["horizon"],
                   help=f"MPC horizon N (default {cat['mpc']['horizon']})")
    s.add_argument("--iters", type=int, default=cat["mpc"]["iters"],
                   help=f"FISTA iterations per step (default {cat['mpc']['iters']})")
    s.add_argument("--x64", action="store_true", help="run in float64")

    _add_sweep_parser(sub)

    rep = sub.add_parser("report", help="statistics, figures and tables (HTML, Markdown, CSV, LaTeX) from a "
                                        "sweep's episodes (docs/report.md)",
                         description="Write the statistical report of a sweep's episodes.")
    rep.add_argument("sweep", type=pathlib.Path, help="the sweep's output, runs/NAME.parquet")
    rep.add_argument("--no-cache", action="store_true",
                     help="do not use the persistent compilation cache for the gallery's re-simulations")
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
    rep.add_argument("--animate", action="store_true",
                     help="also animate the gallery's worst episodes (GIF in the page, MP4 beside it; the video extra)")
    rep.add_argument("--svg", action="store_true", help="also write every figure as SVG (vector graphics for a paper)")
    rep.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples (default 2000)")
    rep.add_argument("--confidence", type=float, default=0.95, help="interval level (default 0.95)")
    rep.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    rep.add_argument("--profile-metric",
                     help="metric of the performance profile, higher is better (default spl; of a swarm sweep "
                          "at_goal)")
    rep.add_argument("--margin", action="append", default=[], metavar="METRIC=VALUE",
                     help="relevance margin of a metric, overriding its registered one (repeatable; rates as "
                          "proportions, e.g. success=0.05)")
    rep.add_argument("--primary", action="append", default=[], metavar="METRIC",
                     help="a metric of the primary Holm family (repeatable; default success and collision, of a "
                          "swarm sweep swarm_success and agent_collision); every other metric is exploratory")
    rep.add_argument("--pair-on", default="", metavar="COLUMN[,COLUMN...]",
                     help="with several baseline settings, pair each setting with the baseline that equals it on "
                          "these columns (default: every swept column the baseline reads)")
    rep.add_argument("--efficiency", choices=("both-success", "all-pairs"), default="both-success",
                     help="compare metrics meaningful only on successes on the pairs where both settings succeed "
                          "(default) or on all pairs")

    tune = sub.add_parser("tune", help="learn the gains by gradient descent through the closed loop and test them "
                                       "against defaults, grid and random search (docs/tune.md)",
                          description="Learn gains through the closed loop, then test them on held-out fields.")
    tune.add_argument("spec", type=pathlib.Path, help="tune spec TOML (see docs/tune.md)")
    tune.add_argument("--out", type=pathlib.Path,
                      help="output folder (default runs/tune-NAME); a checkpoint there is resumed")
    tune.add_argument("--quiet", action="store_true", help="no progress bar or messages")

    cmp = sub.add_parser("compare", help="methods each at its tuned best under equal budgets, tested on held-out "
                                         "fields with paired statistics (docs/compare.md)",
                         description="Select every method's gains on training fields under the same episode budget "
                                     "for several selection seeds, then test all on held-out fields and report.")
    cmp.add_argument("spec", type=pathlib.Path, help="compare spec TOML (see docs/compare.md)")
    cmp.add_argument("--out", type=pathlib.Path,
                     help="output folder (default runs/compare-NAME); what is finished there is reused")
    cmp.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples of the report (default 2000)")
    cmp.add_argument("--gallery", type=int, default=0, help="worst test episodes to re-simulate and draw (default 0)")
    cmp.add_argument("--no-cache", action="store_true",
                     help="do not use the persistent compilation cache nor the oracle's kept answers")
    cmp.add_argument("--shard", metavar="I/N",
                     help="run only shard I of N: every N-th selection and, once all selections are in --out, "
                          "shard I/N of the test sweep; then the command without --shard writes the report "
                          "(docs/compare.md)")
    cmp.add_argument("--quiet", action="store_true", help="no progress bar or messages")

    card = sub.add_parser("scorecard", help="rank a method against the shipped zoo on a frozen benchmark, paired "
                                            "with the stored episodes (docs/scorecard.md)",
                          description="Select a method's gains under a frozen scorecard's budget and seeds, fly its "
                                      "held-out fields and rank it against every stored zoo member, paired field by "
                                      "field; without --method, print the stored leaderboard.")
    card.add_argument("--card", default="v1",
                      help="a shipped scorecard's version (default v1) or a folder holding a scorecard.toml")
    card.add_argument("--method", help="the method to score: PLANNER or PLANNER+FILTER (a plugin's, with --plugin)")
    card.add_argument("--name", help="the method's row in the leaderboard (default the method)")
    card.add_argument("--out", type=pathlib.Path,
                      help="output folder (default runs/scorecard-VERSION-NAME); what is finished there is reused")
    card.add_argument("--rescore", action="store_true",
                      help="score the whole zoo again and store it beside the scorecard (hours on a CPU)")
    card.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples (default 2000)")
    card.add_argument("--no-cache", action="store_true", help="do not use the persistent compilation cache")
    card.add_argument("--quiet", action="store_true", help="no progress bar or messages")

    bench = sub.add_parser("bench", help="speed: the engine against a vectorised numpy peer and the numpy + OSQP "
                                         "oracle, and whole sweeps",
                           description="Measure the engine's and the sweep's speed on this machine.")
    bsub = bench.add_subparsers(dest="bench", required=True)
    eng = bsub.add_parser("engine", help="the engine against a vectorised numpy peer and the numpy + OSQP oracle "
                                         "on the same fields",
                          description="Time the batched engine, the same closed loop in numpy vectorised over the "
                                      "fields, and the per-field numpy + OSQP oracle on the same fields, interleaved "
                                      "in one run.")
    eng.add_argument("--fields", type=int, default=1024, help="fields in the engine's batch (default 1024)")
    eng.add_argument("--obstacles", type=int, default=16, help="obstacle slots per field (default 16)")
    eng.add_argument("--horizon", type=int, default=20, help="MPC horizon N (default 20)")
    eng.add_argument("--iters", type=int, default=30, help="FISTA iterations (default 30)")
    eng.add_argument("--steps", type=int, default=300, help="control steps per episode (default 300)")
    eng.add_argument("--oracle-fields", type=int, default=3,
                     help="fields run by the numpy + OSQP oracle (default 3; 0: skip it)")
    eng.add_argument("--vectorised-steps", type=int, default=30,
                     help="control steps of the vectorised numpy peer on all fields, per timed round (default 30; "
                          "0: skip it)")
    eng.add_argument("--family", default="clutter", choices=families, metavar="NAME",
                     help="scenario family (default clutter)")
    eng.add_argument("--width", type=int, help="vmap width (default: 1024 on CPU, 4096 on accelerators)")
    eng.add_argument("--devices", type=int, default=1,
                     help="split the fields over N devices (on CPU the host is split into N devices, as "
                          "`jaxapf sweep --devices` does; default 1)")
    eng.add_argument("--json", action="store_true", help="print one JSON object")
    bwo = bsub.add_parser("world", help="what sensing, wind, the quadrotor, each Crazyflie fidelity, the CBF filter "
                                        "and the other planners (MPPI per sample count) cost per scenario-step, "
                                        "against basic in the ideal world",
                          description="Time the closed loop with each component (noisy sensor, wind, quadrotor "
                                      "plant, the Crazyflie at each fidelity of drone-models, CBF filter, another "
                                      "planner, MPPI with 64, 256 and 1,024 samples, the keep-out MPC) against "
                                      "basic in the ideal world, interleaved in one run.")
    bwo.add_argument("--fields", type=int, default=256, help="fields in the batch (default 256)")
    bwo.add_argument("--steps", type=int, default=200, help="control steps per episode (default 200)")
    bwo.add_argument("--substeps", type=int, default=10,
                     help="quadrotor and Crazyflie sub-steps per control step (default 10)")
    bwo.add_argument("--repeats", type=int, default=3, help="timed runs of each variant, interleaved (default 3)")
    bwo.add_argument("--json", action="store_true", help="print one JSON object")
    bsm = bsub.add_parser("swarm", help="what a swarm step costs for 1 to 64 UAVs (the O(A²) interaction)",
                          description="Time circle_swap swarms of 1, 2, 4, ..., 64 UAVs on about the same number of "
                                      "UAVs per call: us per swarm-step and per UAV-step, compile time, working "
                                      "memory.")
    bsm.add_argument("--agents", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64],
                     help="swarm sizes (default 1 2 4 8 16 32 64)")
    bsm.add_argument("--uavs", type=int, default=256, help="UAVs per compiled call, about (default 256)")
    bsm.add_argument("--steps", type=int, default=200, help="control steps per episode (default 200)")
    bsm.add_argument("--repeats", type=int, default=3, help="timed runs of each size, interleaved (default 3)")
    bsm.add_argument("--json", action="store_true", help="print one JSON object")
    bsw = bsub.add_parser("sweep", help="streaming vs fixed-length engine, the whole sweep path, 2 CPU devices",
                          description="Time a sweep's episodes with the streaming and the fixed-length engine (bare "
                                      "evaluate calls, interleaved), the whole sweep end to end, and the sweep on "
                                      "several CPU devices.")
    bsw.add_argument("spec", nargs="?", type=pathlib.Path,
                     help="a sweep spec TOML (default: a built-in 2,048-episode study)")
    bsw.add_argument("--repeats", type=int, default=3, help="timed runs of each, interleaved (default 3)")
    bsw.add_argument("--sharded-devices", type=int, default=2,
                     help="also time the sweep with the host split into N CPU devices (default 2; 0: skip)")
    bsw.add_argument("--json", action="store_true", help="print one JSON object")

    lst = sub.add_parser("list", help="what is registered: " + ", ".join(cat["lists"]),
                         description="Print a registry, one line per entry.")
    lst.add_argument("what", choices=tuple(cat["lists"]), help="which registry")
    return parser


def _add_sweep_parser(sub: argparse._SubParsersAction) -> None:
    ver = sub.add_parser("sweep-verify", prog="jaxapf sweep verify",
                         description="Say whether a sweep's output is complete and sound: every expected episode "
                                     "exactly once, every part's checksum, one spec and format; list what is not. "
                                     "Exit status 0: complete and sound; 1: not.")
    ver.add_argument("out", type=pathlib.Path, help="the sweep's output folder, runs/NAME.parquet")
    mrg = sub.add_parser("sweep-merge", prog="jaxapf sweep merge",
                         description="Combine sweep outputs written apart (shard folders) into one; refuses folders "
                                     "of another spec or version, never doubles a row.")
    mrg.add_argument("sources", type=pathlib.Path, nargs="+", help="the folders to merge")
    mrg.add_argument("--out", type=pathlib.Path, required=True, help="the merged output folder")
    sw = sub.add_parser("sweep", help="run a study stated in a TOML spec into a Parquet dataset (docs/sweep.md); "
                                      "`jaxapf sweep verify OUT` checks one, `jaxapf sweep merge A B --out OUT` "
                                      "combines folders",
                        description="Run a study stated in a TOML spec into a Parquet dataset; a rerun resumes. "
                                    "`jaxapf sweep verify OUT` says whether an output is complete and sound; "
                                    "`jaxapf sweep merge A B ... --out OUT` combines outputs written apart.")
    sw.add_argument("spec", type=pathlib.Path, help="sweep spec TOML, e.g. sweeps/compare-small.toml")
    sw.add_argument("--out", type=pathlib.Path, help="output dataset directory (default runs/NAME.parquet)")
    sw.add_argument("--dry-run", action="store_true",
                    help="print settings, episodes, compiled variants, chunks, time and memory estimates; run nothing")
    sw.add_argument("--gains", type=pathlib.Path, metavar="FILE",
                    help="TOML of gains (e.g. a tuning result) overriding the spec's [gains]")
    sw.add_argument("--overwrite", action="store_true",
                    help="replace the parts of a different (or the same) sweep in --out")
    sw.add_argument("--repair", action="store_true",
                    help="remove the damaged parts found in --out (checksum mismatch, truncated, unreadable) and "
                         "recompute exactly their chunks")
    sw.add_argument("--memory-budget", metavar="SIZE",
                    help="working-set budget of one chunk, e.g. 256M, 2G (default: 256M on CPU, half the free "
                         "memory of an accelerator)")
    sw.add_argument("--policy", choices=("cpu", "accelerator"),
                    help="how chunks fill the device (default: the backend's): cpu refills a quarter-wide set of "
                         "slots; accelerator flies a chunk's episodes side by side and pads every family to one "
                         "obstacle slot count, so a method is one program (docs/performance.md)")
    sw.add_argument("--chunk-fields", type=int, metavar="N", help="fields per chunk (default: from the memory budget)")
    sw.add_argument("--devices", type=int, metavar="N",
                    help="on CPU, split the host into N JAX devices (default 1: XLA already spreads the "
                         "engine's wide kernels over the cores)")
    sw.add_argument("--cache-dir", type=pathlib.Path, metavar="DIR",
                    help="persistent XLA compilation cache (default ~/.cache/jaxapf/xla)")
    sw.add_argument("--no-cache", action="store_true",
                    help="no persistent compilation cache, and the solvability oracle asked anew (its answers are "
                         "kept in ~/.cache/jaxapf/oracle otherwise)")
    sw.add_argument("--shard", metavar="I/N",
                    help="run only shard I of N (0 <= I < N): a fixed, cost-balanced share of the chunks, the same "
                         "for every process reading the spec; shards run at any time, on one output or each in "
                         "its own folder (then `jaxapf sweep merge`), e.g. a Slurm array task: "
                         "--shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT")
    sw.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                    help="run the chunks on a Ray cluster's workers (pip install 'jaxapf[ray]'): ADDRESS as "
                         "`ray start` prints it, or `auto` for the one started on this machine; without ADDRESS, "
                         "RAY_ADDRESS or a Ray instance started for this run")
    sw.add_argument("--ray-cpus", type=float, default=1.0, metavar="C",
                    help="CPUs of one Ray worker (default 1; one worker per slot runs the chunks)")
    sw.add_argument("--ray-gpus", type=float, default=0.0, metavar="G",
                    help="GPUs of one Ray worker (default 0; 1 on GPU nodes)")
    sw.add_argument("--quiet", action="store_true", help="no progress bar")
    sw.add_argument("--x64", action="store_true", help="run in float64")


def _simulate(args: argparse.Namespace) -> int:
    if args.x64:
        import jax

        jax.config.update("jax_enable_x64", True)
    from ..config import MPCConfig, SimConfig
    from ..control import scales_set
    from ..io.lock import check_writable
    from ..scenarios import FAMILIES, family_params
    from ..scenarios.swarms import swarm_params
    from ..simulate import format_metrics_table, simulate_runs, write_outputs
    from ..simulate.animate import animate, tracks_of_runs, tracks_of_swarm
    from ..simulate.episodes import defining_field
    from ..simulate.swarm import simulate_swarm, write_swarm_outputs
    from ..spec.settings import traced_weights
    from ..validation import MAX_FIELDS, MAX_SEED, ConfigError, check_int

    check_int("--seed", args.seed, 0, MAX_SEED)
    swarm = args.family in _names("swarm-families")
    chosen = args.field is None
    if not chosen:
        check_int("--field", args.field, 0, MAX_FIELDS - 1)
    if args.agents is not None and not swarm:
        raise ConfigError(f"--agents: {args.family} is a single-UAV family; --agents sets a swarm family's UAVs")
    overrides = {} if args.agents is None else {"agents": args.agents}
    if args.animate:
        from ..simulate.animate import ffmpeg

        ffmpeg()  # a missing video extra is said before the episodes fly, not after
    params = swarm_params(args.family, **overrides) if swarm else family_params(args.family)
    if chosen:
        args.field = 0 if swarm else defining_field(args.family, args.seed, params)
        family = None if swarm else FAMILIES.get(args.family)
        if family is not None and len(family.kinds) > 1:
            print(f"note: field {args.field} is the first {family.defining} field of {args.family} at seed "
                  f"{args.seed} (its defining kind; --field N flies another)")
    gains = _gains(args)
    check_writable(args.out)
    t_max = args.t_max if args.t_max is not None else params.t_max
    components = {c["key"]: getattr(args, c["key"]) for c in _catalog()["components"] if c["key"] != "method"}
    # the MPC's weights follow the gains only where a scale is set, as in sweep, tune and compare specs
    traced = traced_weights({}, scales_set(gains.floats()))
    sim = SimConfig.from_flat(method=args.methods[0], **components, convention=args.convention, dt=args.dt,
                              t_max=t_max, **traced)
    mpc = MPCConfig(horizon=args.horizon, iters=args.iters)
    start = time.perf_counter()
    config = {"command": "simulate", "family": args.family, "seed": args.seed, "field_index": args.field,
              "methods": args.methods, "gains": gains.floats(), "sim": sim.flat() | {"method": None},
              "mpc": vars(mpc), **({"scenario": overrides} if overrides else {})}
    if swarm:
        field, runs, table = simulate_swarm(args.family, args.seed, args.field, args.methods, gains, sim, mpc,
                                            overrides)
        paths = write_swarm_outputs(args.out, field, runs, table, config)
        title, metrics = field.field.title, format_metrics_table(runs)
        if args.animate:
            paths += animate(tracks_of_swarm(runs, field), field.field, args.out, title=title)
    else:
        field, runs, table = simulate_runs(args.family, args.seed, args.field, args.methods, gains, sim, mpc)
        paths = write_outputs(args.out, field, runs, table, config)
        title, metrics = field.title, format_metrics_table(runs)
        if args.animate:
            paths += animate(tracks_of_runs(runs, field), field, args.out, title=title)
    print(f"{title}: {sim.episode.steps} steps of {sim.episode.dt:g} s, {len(runs)} methods "
          f"in {time.perf_counter() - start:.1f} s")
    print(metrics)
    for note in ([] if swarm else stall_notes(args.family, runs)):
        print(note)
    print(f"wrote {len(paths)} files to {args.out}/:", ", ".join(p.name for p in paths))
    return 0


def stall_notes(family: str, runs: Sequence[Any]) -> list[str]:
    """A line for each run that stalled (the metric ``stalled``): where, and that it is what the potential
    does there, not a failure of the program; on ``paper_static`` that the paper's scenario 1 is not
    reproduced (study 1: every method stalls on every one of its fields)."""
    out = [f"note: {r.label} stalled {r.metrics['final_distance']:.1f} m from the goal: it stopped making progress "
           "in a local minimum of its potential field (metric `stalled`)" for r in runs if r.metrics.get("stalled")]
    if out and family == "paper_static":
        out.append("note: on paper_static every method stalls, on every field (study 1, analysis/README.md): the "
                   "paper's scenario 1 (where it reports the weighted APF going around) does not reproduce; try "
                   "--family trap or clutter")
    return out


def _bench(args: argparse.Namespace) -> int:
    from ..validation import check_int

    if args.bench == "world":
        from ..bench.world import format_world_benchmark, run_world_benchmark

        result = run_world_benchmark(fields=args.fields, steps=args.steps, substeps=args.substeps,
                                     repeats=args.repeats)
        print(json.dumps(result, indent=2) if args.json else format_world_benchmark(result))
        return 0
    if args.bench == "swarm":
        from ..bench.swarm import format_swarm_benchmark, run_swarm_benchmark

        result = run_swarm_benchmark(agents=args.agents, uavs=args.uavs, steps=args.steps, repeats=args.repeats)
        print(json.dumps(result, indent=2) if args.json else format_swarm_benchmark(result))
        return 0
    if args.bench == "sweep":
        from ..bench.sweep import format_sweep_benchmark, run_sweep_benchmark
        from ..sweep import read_toml

        check_int("--repeats", args.repeats, 1)
        check_int("--sharded-devices", args.sharded_devices, 0)
        result = run_sweep_benchmark(read_toml(args.spec) if args.spec else None,
                                     sharded_devices=args.sharded_devices, repeats=args.repeats)
        print(json.dumps(result, indent=2) if args.json else format_sweep_benchmark(result))
        return 0
    from ..bench.engine import format_benchmark, run_benchmark

    check_int("bench.devices", args.devices, 1)
    if args.devices != 1:
        from ..engine.runtime import configure_jax

        configure_jax(cpu_devices=args.devices)
    result = run_benchmark(fields=args.fields, obstacles=args.obstacles, horizon=args.horizon, iters=args.iters,
                           steps=args.steps, oracle_fields=args.oracle_fields, family=args.family, width=args.width,
                           devices=args.devices, vectorised_steps=args.vectorised_steps)
    print(json.dumps(result, indent=2) if args.json else format_benchmark(result))
    return 0


def _tune(args: argparse.Namespace) -> int:
    from ..tune import TuneError, run_tune
    from ..validation import ConfigError

    try:
        run_tune(args.spec, args.out, quiet=args.quiet)
    except ConfigError:  # bad input (a damaged checkpoint among them): one line, status 2
        raise
    except TuneError as err:
        print(f"jaxapf tune: error: {err}", file=sys.stderr)
        return 1
    return 0


def _compare(args: argparse.Namespace) -> int:
    from ..compare import run_compare
    from ..engine.runtime import configure_jax, default_cache_dir
    from ..sweep.plan import parse_shard
    from ..tune import TuneError
    from ..validation import ConfigError

    shard = parse_shard(args.shard) if args.shard is not None else None
    configure_jax(cache_dir=None if args.no_cache else default_cache_dir())
    try:
        run_compare(args.spec, args.out, quiet=args.quiet, resamples=args.resamples, gallery=args.gallery,
                    shard=shard, answers=None if args.no_cache else default_cache_dir("oracle"))
    except ConfigError:
        raise
    except TuneError as err:
        print(f"jaxapf compare: error: {err}", file=sys.stderr)
        return 1
    return 0


def _scorecard(args: argparse.Namespace) -> int:
    from ..compare.scorecard import load_scorecard, score_method, score_zoo
    from ..engine.runtime import configure_jax, default_cache_dir
    from ..io.names import read_own
    from ..tune import TuneError
    from ..validation import ConfigError

    where = pathlib.Path(args.card)
    card = load_scorecard(folder=where) if (where / "scorecard.toml").is_file() else load_scorecard(args.card)
    if args.rescore and args.method:
        raise ConfigError("--rescore scores the zoo; --method scores one method against it: give one of them")
    if not (args.rescore or args.method):
        print(read_own(card.stored("leaderboard.md")).decode("utf-8"), end="")
        return 0
    configure_jax(cache_dir=None if args.no_cache else default_cache_dir())
    label = args.name or args.method or "zoo"
    out = args.out if args.out is not None else pathlib.Path("runs") / f"scorecard-{card.version}-{label}"
    try:
        if args.rescore:
            score_zoo(card, out, quiet=args.quiet)
            print(f"scored the zoo of scorecard {card.version} into {card.folder}")
        else:
            board = score_method(card, args.method, out, name=args.name, quiet=args.quiet, resamples=args.resamples)
            row = board.table[board.table["method"] == label].iloc[0]
            print(f"{label}: rank {int(row['rank'])} of {len(board.table)} on scorecard {card.version}; wrote "
                  f"{out}/leaderboard.md, leaderboard.html, leaderboard.csv, comparisons.csv")
    except TuneError as err:
        print(f"jaxapf scorecard: error: {err}", file=sys.stderr)
        return 1
    return 0


def _report(args: argparse.Namespace) -> int:
    from ..report.worker import close, spawn

    # the second process starts first: its imports run beside this one's
    pool = spawn() if args.gallery > 0 else None
    try:
        return _report_with(args, pool)
    except BaseException:  # stopped or failed: the worker's work is not wanted any more
        if pool is not None:
            close(pool, stop=True)
            pool = None
        raise
    finally:
        if pool is not None:
            close(pool, wait=False)


def _report_with(args: argparse.Namespace, pool: Any) -> int:
    from ..engine.runtime import configure_jax, default_cache_dir
    from ..io.lock import writing
    from ..report import ReportOptions, build_report

    configure_jax(cache_dir=None if args.no_cache else default_cache_dir())

    heatmap = None if args.heatmap.strip().lower() in ("", "none") else tuple(
        c.strip() for c in args.heatmap.split(","))
    options = ReportOptions(baseline=args.baseline, where=tuple(args.where), heatmap=heatmap,
                            gallery=args.gallery, resamples=args.resamples, confidence=args.confidence,
                            seed=args.seed, profile_metric=args.profile_metric, margins=_margins(args.margin),
                            efficiency=args.efficiency, svg=args.svg, animate=args.animate,
                            primary=tuple(args.primary),
                            pair_on=tuple(c.strip() for c in args.pair_on.split(",") if c.strip()))
    name = args.sweep.name.removesuffix(".parquet") or "report"
    out = args.out if args.out is not None else pathlib.Path("reports") / name
    start = time.perf_counter()
    with writing(out, "the files written so far are kept (the report may be incomplete)"):
        result = build_report(args.sweep, out, options, pool)
    if result.incomplete:
        print(f"INCOMPLETE SWEEP: {result.incomplete}")
    print(f"report of {args.sweep}: {len(result.summary)} setting × family rows, "
          f"{len(result.comparisons)} paired comparisons in {time.perf_counter() - start:.1f} s")
    for note in result.notes:
        print(f"note: {note}")
    print(f"wrote {out}/report.html, report.md, summary.csv, comparisons.csv, table.tex and "
          f"{sum(1 for p in result.paths if p.parent.name == 'figures')} figure files")
    return 0


def _margins(texts: Sequence[str]) -> tuple[tuple[str, float], ...]:
    from ..validation import ConfigError

    out = []
    for text in texts:
        name, sep, value = text.partition("=")
        try:
            out.append((name.strip(), float(value)))
        except ValueError:
            raise ConfigError(f"--margin {text!r} must look like METRIC=NUMBER, e.g. success=0.05") from None
        if not sep:
            raise ConfigError(f"--margin {text!r} must look like METRIC=NUMBER, e.g. success=0.05")
    return tuple(out)


def _sweep(args: argparse.Namespace) -> int:
    from ..engine.runtime import configure_jax, default_cache_dir
    from ..sweep import dry_run, load_spec, parse_size, run_sweep
    from ..sweep.cluster import RayCluster, RaySession
    from ..sweep.plan import parse_shard
    from ..sweep.run import check_options
    from ..validation import ConfigError, check_int

    budget = None if args.memory_budget is None else parse_size(args.memory_budget)
    shard = parse_shard(args.shard) if args.shard is not None else None
    if args.devices is not None:
        check_int("--devices", args.devices, 1)
    if args.chunk_fields is not None:
        check_int("--chunk-fields", args.chunk_fields, 1)
    cluster = None if args.ray is None else RayCluster(args.ray or None, args.ray_cpus, args.ray_gpus)
    if cluster is None and (args.ray_cpus, args.ray_gpus) != (1.0, 0.0):
        raise ConfigError("--ray-cpus and --ray-gpus size the workers of --ray; give --ray too")
    check_options(shard, args.devices, args.overwrite, cluster)
    configure_jax(x64=args.x64, cache_dir=None if args.no_cache else args.cache_dir or default_cache_dir(),
                  cpu_devices=args.devices or 1)
    spec = load_spec(args.spec, args.gains)
    out = args.out or pathlib.Path("runs") / f"{spec.name}.parquet"
    if args.dry_run:
        options = dict(memory_budget=budget, chunk_fields=args.chunk_fields, policy=args.policy)
        if cluster is not None:  # planned for the workers' backend, one device per worker
            with RaySession(cluster) as session:
                found = session.probe()
                options |= dict(devices=1, backend=found["backend"], free=found.get("free"))
        print(dry_run(spec, out, overwrite=args.overwrite, repair=args.repair, shard=shard, **options))
        return 0
    result = run_sweep(spec, out, memory_budget=budget, chunk_fields=args.chunk_fields, overwrite=args.overwrite,
                       repair=args.repair, quiet=args.quiet, shard=shard, devices=args.devices, ray=cluster,
                       policy=args.policy, answers=None if args.no_cache else default_cache_dir("oracle"))
    print(result.summary(spec.name))
    return 0


def _sweep_verify(args: argparse.Namespace) -> int:
    from ..sweep.audit import audit_folder, describe_audit
    from ..validation import ConfigError

    if not args.out.is_dir():
        raise ConfigError(f"{args.out} is not a folder")
    found, meta = audit_folder(args.out)
    print(describe_audit(args.out, found, meta))
    return 0 if found.complete else 1


def _sweep_merge(args: argparse.Namespace) -> int:
    from ..sweep.merge import merge_outputs

    print(merge_outputs(args.sources, args.out).summary())
    return 0


def _list(args: argparse.Namespace) -> int:
    """One line per entry; under a component, one line per gain it reads, worded as ``list gains``."""
    cat = _catalog()
    entries = cat["lists"][args.what]
    if args.what == "families":  # the swarm families are families too (jaxapf list swarm-families alone)
        entries = entries + [{**e, "describe": f"swarm: {e['describe']}"} for e in cat["lists"]["swarm-families"]]
    gains = {e["name"]: e["describe"] for e in cat["lists"]["gains"]}
    width = max(len(e["name"]) for e in entries)
    for entry in entries:
        print(f"{entry['name']:<{width}}  {entry['describe']}")
        for gain in entry.get("gains", ()):
            print(f"{'':<{width}}    {gain}: {gains.get(gain, '')}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """The command line on ``argv`` (default ``sys.argv[1:]``); returns the exit status. While it runs in
    the main thread, SIGINT and SIGTERM stop it with one line saying what was kept (:mod:`.stops`)."""
    import signal

    from .stops import on_signal, stopped

    main_thread = threading.current_thread() is threading.main_thread()
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)} if main_thread else {}
    running: list[str] = []  # the command, once it runs
    try:
        return _main(list(sys.argv[1:] if argv is None else argv), running)
    except KeyboardInterrupt as stop:  # before the command ran (plugins, catalogue, parsing), or as it ended
        return stopped(stop, f"jaxapf {running[0].replace('-', ' ')}" if running else "jaxapf",
                       _KEPT[running[0]] if running else "nothing was written")
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


#: The least address space (``ulimit -v``) a command is started with [bytes]: XLA's CPU runtime and the
#: report's second process reserve far more than they use, and below this they abort in native code
#: instead of saying so (a report with a gallery aborted at 3.0 GB and ran at 3.5 GB on the 2-core CPU).
MIN_ADDRESS_SPACE = 4 * 2**30


def _check_address_space() -> None:
    """One line, status 2, where ``ulimit -v`` leaves less than :data:`MIN_ADDRESS_SPACE`."""
    import resource

    from ..validation import ConfigError

    soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    if soft != resource.RLIM_INFINITY and soft < MIN_ADDRESS_SPACE:
        raise ConfigError(f"this process may map only {soft / 2**30:.1f} GiB of address space (ulimit -v); JAX's "
                          f"runtime needs at least {MIN_ADDRESS_SPACE // 2**30} GiB: raise the limit "
                          "(ulimit -v unlimited) and rerun; nothing was written")


def _main(argv: list[str], running: list[str]) -> int:
    global _CATALOG
    from ..spec.plugins import load_plugin, plugin_failure
    from ..validation import ConfigError, first_line
    from .stops import stopped

    # plugins register components (and their gain flags) before the parser is built from the registries
    early = argparse.ArgumentParser(add_help=False)
    early.add_argument("--plugin", action="append", default=[])
    known, _ = early.parse_known_args(argv)
    try:
        for plugin in known.plugin:
            load_plugin(plugin, "--plugin")
    except ConfigError as err:
        print(f"jaxapf: error: {inert(str(err))}", file=sys.stderr)
        return 2
    from .catalog import catalog

    # with plugins, or with the registries imported already (their entries may have changed in this process),
    # read them live: that costs nothing more then
    _CATALOG = catalog(fresh=bool(known.plugin) or "jaxapf.engine.components" in sys.modules)
    at = 0  # `jaxapf [--plugin X ...] sweep verify|merge ...` is the command sweep-verify|sweep-merge
    while at < len(argv) and argv[at].startswith("--plugin"):
        at += 1 if "=" in argv[at] else 2
    if argv[at:at + 2] in (["sweep", "verify"], ["sweep", "merge"]):
        argv = argv[:at] + [f"sweep-{argv[at + 1]}"] + argv[at + 2:]
    args = build_parser().parse_args(argv)
    command = args.command.replace("-", " ")  # `sweep-verify` is `jaxapf sweep verify`
    import warnings

    from ..validation import Interrupted

    def one_line(message, category, filename, lineno, file=None, line=None):
        print(f"jaxapf {command}: warning: {inert(str(message).strip().splitlines()[0])}", file=sys.stderr)

    running.append(args.command)
    try:
        if args.command != "list":
            _check_address_space()
        with warnings.catch_warnings(), contextlib.redirect_stdout(InertLines(sys.stdout)):
            warnings.showwarning = one_line
            return {"simulate": _simulate, "bench": _bench, "tune": _tune, "compare": _compare,
                    "scorecard": _scorecard, "report": _report,
                    "sweep": _sweep, "sweep-verify": _sweep_verify, "sweep-merge": _sweep_merge,
                    "list": _list}[args.command](args)
    except ConfigError as err:
        print(f"jaxapf {command}: error: {inert(str(err))}", file=sys.stderr)
        return 2
    except Interrupted as err:  # a runner's own line of what it kept
        stop = err.__context__ if isinstance(err.__context__, KeyboardInterrupt) else err
        return stopped(stop, f"jaxapf {command}", str(err).removeprefix("interrupted; "))
    except KeyboardInterrupt as stop:
        return stopped(stop, f"jaxapf {command}", _KEPT[args.command])
    except ImportError as err:
        print(f"jaxapf {command}: error: {inert(str(err))}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader went away (`jaxapf ... | head`): stop quietly, as Python's docs advise
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except MemoryError:
        print(f"jaxapf {command}: error: out of memory; {_KEPT[args.command]}", file=sys.stderr)
        return 2
    except Exception as err:  # the system refused, or a plugin's own code failed: one line; a bug keeps its traceback
        if isinstance(err, OSError) and err.errno is not None:  # a full disk, a lost mount, permissions
            import errno

            full = " (the file system is full)" if err.errno in (errno.ENOSPC, errno.EDQUOT) else ""
            where = f"{err.filename}: " if err.filename else ""
            print(f"jaxapf {command}: error: {where}{err.strerror or first_line(err)}{full}; {_KEPT[args.command]}",
                  file=sys.stderr)
            return 2
        failed = plugin_failure(err)
        if failed is None:
            raise
        print(f"jaxapf {command}: error: {inert(failed)}; {_KEPT[args.command]}", file=sys.stderr)
        return 2

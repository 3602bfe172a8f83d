"""Study 17: the planners the field flies (MPPI, the keep-out MPC) against the paper's potential field.

``jaxapf compare sweeps/flown-planners.toml``: study 11's protocol (the same selection budget, seeds,
families, held-out fields and test seed, one verdict function, Holm) with ``mppi`` (sampling-based MPC)
and ``keepout_mpc`` (every obstacle a constraint at every horizon step) beside the paper's
``direction_velocity``, ``basic`` and study 11's leader ``velocity_obstacle``. Each setting is paired with
``basic`` of the same selection, and in a second report with ``direction_velocity``.

Then the swarms of study 16's two open flows (``circle_swap``, ``crossing_flows``) with 8 and 32 UAVs,
every method at each of its three selections (chosen for a UAV alone), 64 held-out fields per family
and size (study 16's seed), every UAV seeing its 8 nearest neighbours; each paired with ``basic`` of the
same selection on swarm success, collisions between UAVs and deadlock (``swarm_study.summarise``: the
verdict function, Holm over all of these comparisons).

    python analysis/flown_planners.py     # the comparison: the selection ~1 h, the held-out flights ~35 min;
                                          # the swarms ~5 h of one core, cached per cell under runs/flown-swarms/
    python analysis/flown_planners.py --kept-swarms   # the swarms' committed tables, verdicts derived again
"""

from __future__ import annotations

import pathlib

import numpy as np
import pandas as pd
import study
import swarm_study
from planner_benchmark import SEEDS, run_benchmark

FLOWS = ("circle_swap", "crossing_flows")
#: The planners the paper's field flies (module docstring): the question's other side.
FLOWN = ("velocity_obstacle", "mppi", "keepout_mpc")
AGENTS = (8, 32)


def swarm_cells(out: pathlib.Path, spec) -> pd.DataFrame:
    """Every (flow, A, method) cell, cached under ``runs/flown-swarms/`` as soon as it is done."""
    cache = study.ROOT / "runs" / "flown-swarms"
    cache.mkdir(parents=True, exist_ok=True)
    frames = []
    for agents in AGENTS:
        for family in FLOWS:
            for method in spec.methods:
                path = cache / f"{family}-a{agents:02d}-{method}.parquet"
                if not path.exists():
                    swarm_study.cell(method, family, agents, swarm_study.FIELDS,
                                     source=out / "selection.csv").to_parquet(path, index=False)
                    print(f"  {family} A={agents} {method}: done", flush=True)
                frames.append(pd.read_parquet(path))
    return pd.concat(frames, ignore_index=True)


def swarm_table(rates: pd.DataFrame, comparisons: pd.DataFrame, family: str) -> str:
    """Markdown: per method and A, each outcome in % (mean over the seeds [lowest, highest]) with the seeds'
    verdict marks against ``basic``."""
    head = [f"{m} A = {a}" for m, _ in swarm_study.OUTCOMES for a in AGENTS]
    lines = ["| method | " + " | ".join(head) + " |", "|---|" + "---|" * len(head)]
    part = rates[rates["family"] == family]
    for method in dict.fromkeys(part["method"]):
        cells = []
        for metric, _ in swarm_study.OUTCOMES:
            for a in AGENTS:
                v = part[(part["method"] == method) & (part["agents"] == a)].sort_values("seed")[metric]
                m = comparisons[(comparisons["family"] == family) & (comparisons["metric"] == metric)
                                & (comparisons["method"] == method) & (comparisons["agents"] == a)]
                tag = "".join(swarm_study.MARK[x] for x in m.sort_values("seed")["verdict"])
                cell = f"{100 * v.mean():.1f} [{100 * v.min():.0f}, {100 * v.max():.0f}]"
                cells.append(f"{cell} {tag}" if tag else cell)
        lines.append(f"| `{method}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def swarm_facts(rates: pd.DataFrame, comparisons: pd.DataFrame) -> dict:
    """``swarm``: per flow, A, outcome and method the mean over the seeds; ``swarm_all_seeds``: against
    ``basic`` the verdict all three seeds give (``mixed`` where they differ); ``swarm_agents``,
    ``swarm_comparisons``."""
    out: dict = {"swarm_fields": swarm_study.FIELDS, "swarm_agents": list(AGENTS),
                 "swarm_comparisons": len(comparisons), "swarm": {}, "swarm_all_seeds": {}}
    mean = rates.groupby(["family", "agents", "method"])[[m for m, _ in swarm_study.OUTCOMES]].mean()
    for (family, agents, method), row in mean.iterrows():
        for metric, _ in swarm_study.OUTCOMES:
            out["swarm"].setdefault(family, {}).setdefault(str(agents), {}).setdefault(metric, {})[method] = float(
                row[metric])
    for (family, agents, metric, method), g in comparisons.groupby(["family", "agents", "metric", "method"]):
        out["swarm_all_seeds"].setdefault(family, {}).setdefault(str(agents), {}).setdefault(metric, {})[method] = (
            study.unanimous(g["verdict"]))
    return out


def swarms(out: pathlib.Path, spec, args, runs: pathlib.Path | None) -> tuple[list[str], dict]:
    """The swarm stage (module docstring): its section and facts; its rates and comparisons go to
    ``out/swarms/``. With ``--facts-only`` (``runs`` None) or ``--kept-swarms`` they are read back, their
    verdicts derived again (:func:`swarm_study.committed_tables`), the swarms not flown."""
    folder = out / "swarms"
    if runs is not None and not args.kept_swarms:
        rates, comparisons = swarm_study.summarise(swarm_cells(out, spec))
        folder.mkdir(exist_ok=True)
        rates.to_csv(folder / "rates.csv", index=False)
        comparisons.to_csv(folder / "comparisons.csv", index=False)
    else:
        rates, comparisons = swarm_study.committed_tables(folder)
    lines = ["## Swarms", "",
             f"Study 16's open flows with {' and '.join(map(str, AGENTS))} UAVs, {swarm_study.FIELDS} held-out fields "
             "per flow and size, every method at its three selections (chosen for a UAV alone). Each cell: "
             "rate in % over the fields, mean over the three selections [lowest, highest], then the seeds' "
             "verdicts against `basic` of the same selection (" + ", ".join(f"{v} {k}" for k, v in
                                                                          swarm_study.MARK.items())
             + f"; Holm over all {len(comparisons)} comparisons).", ""]
    for family in FLOWS:
        lines += [f"### {family}", "", swarm_table(rates, comparisons, family), ""]
    unfinished = int(np.sum(rates["n"] != swarm_study.FIELDS))
    if unfinished:
        lines.append(f"{unfinished} cells flew fewer fields than planned.")
    return ["\n".join(lines)], swarm_facts(rates, comparisons)


def question(facts: dict) -> dict:
    """Does the paper's field beat the planners it flies? Each flown planner's pooled success against the
    paper's, every selection seed, seen from the paper's side."""
    paper = facts["verdict"]["paper"]["success"]
    return study.answer_fact({f"{m} {s}": paper[m][s] for m in FLOWN for s in SEEDS}, mirror=True)


def main() -> None:
    run_benchmark(__doc__, "flown_planners", "flown-planners.toml",
                  "Study 17 — the planners the field flies against the paper's potential field", extra=swarms,
                  question=question, flags={"--kept-swarms": "the swarm stage from its committed tables, verdicts "
                                                             "derived again (the swarms, ~5 h, not flown again)"})


if __name__ == "__main__":
    study.entry(main)

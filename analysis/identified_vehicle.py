"""Study 18: do the planners' rankings carry to a vehicle identified from real flights?

Study 11's planners (the same nine methods, budget, seeds and families) on fields scaled to a 32 g
Crazyflie 2.x (``sweeps/crazyflie-scaled.toml``: lengths × 0.25, speeds × 0.5, the vehicle's radius,
limits and the metric thresholds with them; docs/scenarios.md, "Scaled families"). Each method's gains
are selected by ``jaxapf compare`` on the MPC's double integrator (a random search of 512 episodes per
method and seed, seeds 1–3). Then every (method, selection) flies the same held-out fields (the compare
test's: 64 per family, seed 100) on five plants: the double integrator and the Crazyflie cf2x_L250 of
``drone-models`` at each fidelity, ``so_rpy`` (the attitude response fitted to flight data),
``so_rpy_rotor`` (+ the thrust lag), ``so_rpy_rotor_drag`` (+ the identified body drag), and
``first_principles`` (motor speeds, rigid body, commanded by the onboard Mellinger controller of
``drone-controllers``).

What survives the vehicle: the ranking (Spearman's ρ of the methods' pooled success, mean over the seeds,
between two plants, with a bootstrap interval resampling the fields within each family, the same fields
for every plant and method), and the verdicts: each (method, selection) against ``basic`` of the same
selection on the same plant, and each (method, selection) on a Crazyflie against itself on the double
integrator, on success (exact McNemar and TOST within 2 points, Holm over every comparison of the study:
:func:`jaxapf.stats.verdicts`, the verdict function every study uses). Which fidelity step changes them is
read off the ladder double integrator → so_rpy (attitude response) → so_rpy_rotor (thrust lag) →
so_rpy_rotor_drag (body drag); first_principles stands apart (another command path).

    python analysis/identified_vehicle.py     # on 2 cores: selection ~6 min, the compare test ~10 min, the
                                              # flights ~12 min (each arm and method cached under runs/)
"""

from __future__ import annotations

import json
import pathlib
import time

import jax
import numpy as np
import pandas as pd
import study
from robustness import fields, spec_t_max, tuned_gains

STUDY = "identified_vehicle"
SPEC = "crazyflie-scaled.toml"
BASE = "double_integrator"
#: The plants in ladder order, each with what it adds to the one before (first_principles: apart).
PLANTS = {BASE: "the MPC's model", "crazyflie_so_rpy": "attitude response", "crazyflie_so_rpy_rotor": "thrust lag",
          "crazyflie_so_rpy_rotor_drag": "body drag", "crazyflie_first_principles": "motor speeds, onboard Mellinger"}
#: The ladder's rungs above so_rpy and the rung below each (their step's own paired comparison).
RUNGS = {"crazyflie_so_rpy_rotor": "crazyflie_so_rpy", "crazyflie_so_rpy_rotor_drag": "crazyflie_so_rpy_rotor"}
#: The estimator ablation (not in the verdicts): two plants flown again without the integral action.
CHECKS = {f"{BASE}/no_estimator": BASE, "crazyflie_so_rpy/no_estimator": "crazyflie_so_rpy"}
LADDER = (("crazyflie_so_rpy", BASE), ("crazyflie_so_rpy_rotor", "crazyflie_so_rpy"),
          ("crazyflie_so_rpy_rotor_drag", "crazyflie_so_rpy_rotor"), ("crazyflie_first_principles", BASE))
SEEDS = (1, 2, 3)
MARGIN = 0.02
METRICS = ("success", "collision", "stalled", "min_clearance", "time_to_goal", "max_tilt", "saturation_time")
#: What the facts give per plant and method (mean over the seeds and fields).
RATES = ("success", "collision", "stalled", "max_tilt", "saturation_time")
#: The columns of ``outcomes.parquet`` (committed: what ``--facts-only`` works from).
KEPT = ("plant", "method", "seed", "family", "field", "success", "collision", "stalled", "max_tilt", "saturation_time",
        "seconds")
MARK = {"worse": "↓", "better": "↑", "equivalent": "=", "inconclusive": "·"}


def short(plant: str) -> str:
    return plant.removeprefix("crazyflie_")


def fly(spec, source: pathlib.Path, cache: pathlib.Path = study.ROOT / "runs" / "identified-vehicle") -> pd.DataFrame:
    """One row per (arm, method, seed, field) in the ``plant`` column, every plant of :data:`PLANTS` and the
    arms of :data:`CHECKS` (the plant without the estimator): every method's three selections (``source``) as
    one vmap per arm, each (arm, method) cached in ``cache`` as soon as it is flown."""
    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.engine import evaluate

    cache.mkdir(parents=True, exist_ok=True)
    groups = fields(spec, spec.test.fields, spec.test.seed)
    t_max = max(spec_t_max(spec, f) for f in spec.test.families)
    frames = []
    arms = {p: (p, {}) for p in PLANTS} | {arm: (p, {"estimator": "none"}) for arm, p in CHECKS.items()}
    for arm, (plant, changes) in arms.items():
        for method in spec.methods:
            path = cache / f"{arm.replace('/', '-')}-{method.replace('+', '_')}.parquet"
            if not path.exists():
                planner, _, safety = method.partition("+")
                sim = SimConfig.from_flat(**(dict(spec.sim) | changes), method=planner, filter=safety or "none",
                                          t_max=t_max, plant=plant)
                batch = jax.tree_util.tree_map(lambda *x: np.asarray(x, np.float32),
                                               *[Gains(**tuned_gains(method, s, source)) for s in SEEDS])
                rows, start = [], time.perf_counter()
                for scenarios, family in groups:
                    got = jax.device_get(evaluate(scenarios, batch, sim, MPCConfig(), metrics=METRICS))
                    for i, seed in enumerate(SEEDS):
                        rows.append(pd.DataFrame({k: np.asarray(v[i]) for k, v in got.items()}).assign(
                            plant=arm, method=method, seed=seed, family=family,
                            field=np.arange(len(family)) % spec.test.fields))
                pd.concat(rows, ignore_index=True).assign(seconds=time.perf_counter() - start).to_parquet(path)
                print(f"  {arm} {method}: done", flush=True)
            frames.append(pd.read_parquet(path))
    return pd.concat(frames, ignore_index=True)


def outcomes(df: pd.DataFrame, spec, metric: str = "success") -> np.ndarray:
    """``metric`` as an array (plant, method, seed, field), the fields in one order for every cell."""
    df = df.sort_values(["family", "field"], kind="stable")
    out = np.stack([np.stack([np.stack([df[(df["plant"] == p) & (df["method"] == m) & (df["seed"] == s)][metric]
                                        .to_numpy(np.float64) for s in SEEDS]) for m in spec.methods])
                    for p in PLANTS])
    return out


def spearman(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Spearman's ρ between the rows of ``a`` and ``b`` (..., methods), ties at their mean rank."""
    from scipy.stats import rankdata

    ra, rb = rankdata(a, axis=-1), rankdata(b, axis=-1)
    ra, rb = ra - ra.mean(-1, keepdims=True), rb - rb.mean(-1, keepdims=True)
    den = np.sqrt((ra * ra).sum(-1) * (rb * rb).sum(-1))
    return np.where(den > 0, (ra * rb).sum(-1) / np.where(den > 0, den, 1.0), np.nan)


def rank_agreement(success: np.ndarray, strata: np.ndarray, resamples: int) -> dict:
    """Per ladder step: ρ of the methods' pooled success (mean over the seeds) between the two plants,
    its 95 % percentile interval (:func:`jaxapf.stats.bootstrap_cis`: the fields resampled within each
    family, the same resamples for every step, plant, method and seed), and ρ of each seed's selections
    alone. A resample in which every method ties has no ρ and is left out of the interval."""
    from jaxapf.stats import bootstrap_cis

    plants = list(PLANTS)
    scores = success.mean(axis=2)  # (plant, method, field): mean over the seeds
    steps = LADDER + tuple((p, BASE) for p in plants[2:4])

    def rho_of(i: int, j: int):
        def statistic(picked: np.ndarray, axis: int = -1) -> np.ndarray:  # (resamples, fields) field indices
            rows = picked.astype(int)
            return spearman(scores[i][:, rows].mean(-1).T, scores[j][:, rows].mean(-1).T)
        return statistic

    pairs = [(plants.index(plant), plants.index(other)) for plant, other in steps]
    intervals = bootstrap_cis(np.arange(scores.shape[-1], dtype=np.float64), [rho_of(i, j) for i, j in pairs],
                              strata=strata, n_resamples=resamples)
    out = {}
    for (plant, other), (i, j), (lo, hi) in zip(steps, pairs, intervals):
        per_seed = [float(spearman(success[i, :, k].mean(-1), success[j, :, k].mean(-1))) for k in range(len(SEEDS))]
        out[f"{short(plant)}/{short(other)}"] = {"rho": float(spearman(scores[i].mean(-1), scores[j].mean(-1))),
                                                 "lo": lo, "hi": hi, "per_seed": per_seed}
    return out


def comparisons(success: np.ndarray, spec) -> pd.DataFrame:
    """Every paired comparison on success with its verdict (one Holm over all): each (plant, method ≠ basic,
    seed) against ``basic`` of the same seed and plant (``against = "basic"``), each (Crazyflie plant,
    method, seed) against the same selection on the double integrator (``against = "double_integrator"``), and
    on the rungs above so_rpy against the rung below (``against = "rung"``: the thrust lag's and the drag's
    own effect)."""
    plants, methods = list(PLANTS), list(spec.methods)
    b = methods.index(spec.baseline)
    rows = []
    for i, plant in enumerate(plants):
        for j, method in enumerate(methods):
            for k, seed in enumerate(SEEDS):
                now = success[i, j, k].astype(bool)
                if j != b:
                    rows.append({"plant": plant, "method": method, "seed": seed, "against": "basic"}
                                | study.paired_success(now, success[i, b, k].astype(bool)))
                if i:
                    rows.append({"plant": plant, "method": method, "seed": seed, "against": BASE}
                                | study.paired_success(now, success[0, j, k].astype(bool)))
                if plant in RUNGS:  # the ladder's step itself, where its lower rung is not the double integrator
                    rows.append({"plant": plant, "method": method, "seed": seed, "against": "rung"}
                                | study.paired_success(now, success[plants.index(RUNGS[plant]), j, k].astype(bool)))
    return study.mark_verdicts(rows, MARGIN, family=[r["against"] for r in rows])


def verdict_changes(table: pd.DataFrame) -> dict:
    """Per ladder step: the (method, seed) whose verdict against ``basic`` differs between the two plants, how
    many of them turn from better to worse or back (``reversed``), those whose difference to ``basic`` changes
    sign beyond the margin whatever the verdicts (``flips``), and the step's own effect on each (method, seed)'s
    success (``step_effect``: its verdicts against the rung below)."""
    vs = table[table["against"] == "basic"].set_index(["plant", "method", "seed"])["verdict"]
    est = table[table["against"] == "basic"].set_index(["plant", "method", "seed"])["success_change"]
    out = {}
    for plant, other in LADDER:
        flips = [{"method": m, "seed": int(s), "before": float(est[(other, m, s)]), "after": float(est[(plant, m, s)])}
                 for (p, m, s) in est.index if p == plant
                 and max(est[(other, m, s)], est[(plant, m, s)]) > MARGIN
                 and min(est[(other, m, s)], est[(plant, m, s)]) < -MARGIN]
        own = table[(table["plant"] == plant) & (table["against"] == (BASE if other == BASE else "rung"))]
        effect = {v: int((own["verdict"] == v).sum()) for v in ("worse", "better", "equivalent", "inconclusive")}
        changed = [f"{m}/{s}: {vs[(other, m, s)]} → {vs[(plant, m, s)]}"
                   for (p, m, s) in vs.index if p == plant and vs[(plant, m, s)] != vs[(other, m, s)]]
        reversed_ = sum({vs[(other, m, s)], vs[(plant, m, s)]} == {"better", "worse"}
                        for (p, m, s) in vs.index if p == plant)
        out[f"{short(plant)}/{short(other)}"] = {"count": len(changed), "of": int((vs.index.get_level_values(0)
                                                                                  == plant).sum()),
                                                 "reversed": int(reversed_), "changes": changed,
                                                 "estimate_reversed": len(flips), "flips": flips,
                                                 "step_effect": effect}
    return out


def agreement(df: pd.DataFrame, runs: pathlib.Path, spec) -> dict:
    """How many double-integrator episodes flown here have the compare test sweep's outcome (the same
    fields and gains through another program: padded obstacle slots, other batches)."""
    from jaxapf.compare.protocol import rows_of
    from jaxapf.sweep import read_sweep

    test = read_sweep(runs / "test.parquet")[0]
    mine = df[df["plant"] == BASE].set_index(["method", "seed", "family", "field"])["success"]
    same = total = 0
    for method in spec.methods:
        rows = rows_of(test, spec, method)
        for seed in SEEDS:
            part = rows[rows["selection"] == f"seed{seed}"]
            theirs = part.set_index(["family", "field"])["success"].astype(bool)
            ours = mine.loc[(method, seed)].reindex(theirs.index).astype(bool)
            same += int((ours == theirs).sum())
            total += len(theirs)
    return {"same": same, "total": total}


def protocol(spec) -> dict:
    """What was scaled and how (from the spec), the vehicle's mass and the share of the commanded thrust each
    fitted model delivers (``cmd_f_coef``, from ``drone-models``' published parameters)."""
    from jaxapf.world.crazyflie import airframe_parameters

    scales = {tuple(sorted(t["scale"].items())) for t in spec.params.values()}
    (scale,) = scales  # every family scaled alike
    scale = dict(scale)
    fitted = {f: float(airframe_parameters(f, "cf2x_L250")["cmd_f_coef"])
              for f in ("so_rpy", "so_rpy_rotor", "so_rpy_rotor_drag")}
    return {"length_scale": scale["length"], "speed_scale": scale["speed"],
            "time_scale": scale["length"] / scale["speed"], "density_scale": 1.0 / scale["length"] ** 2,
            "r_uav": spec.sim["r_uav"], "v_max": spec.sim["v_max"], "a_max": spec.sim["a_max"],
            "mass_g": 1000 * float(airframe_parameters("first_principles", "cf2x_L250")["mass"]),
            "thrust_delivered_min": min(fitted.values()), "thrust_delivered_max": max(fitted.values()),
            "selection_seeds": list(spec.selection.seeds)}


def per_family(df: pd.DataFrame, spec) -> dict:
    """Per test family: each plant's success per method (mean over the seeds), ρ of the methods' success against
    the double integrator, and the leading method on each plant."""
    out = {}
    for family, rows in df[df["plant"].isin(list(PLANTS))].groupby("family"):
        success = rows.groupby(["plant", "method", "seed"])["success"].mean().groupby(["plant", "method"]).mean()
        table = {short(p): {m: float(success[(p, m)]) for m in spec.methods} for p in PLANTS}
        base = np.array([table[short(BASE)][m] for m in spec.methods])
        out[family] = {"success": table,
                       "rho": {short(p): float(spearman(base, np.array([table[short(p)][m] for m in spec.methods])))
                               for p in PLANTS if p != BASE},
                       "leader": {k: max(v, key=v.get) for k, v in table.items()}}
    return out


def no_estimator(df: pd.DataFrame, spec) -> dict:
    """The estimator ablation: the share of double-integrator episodes whose outcome (success, collision) is the
    same without the integral action, and each method's success on so_rpy without it (mean over the seeds)."""
    key = ["method", "seed", "family", "field"]
    with_, without = (df[df["plant"] == arm].set_index(key)[["success", "collision"]].sort_index()
                      for arm in (BASE, f"{BASE}/no_estimator"))
    same = (with_ == without).all(axis=1)
    so = df[df["plant"] == "crazyflie_so_rpy/no_estimator"].groupby(["method", "seed"])["success"].mean()
    return {"double_integrator_same": float(same.mean()), "double_integrator_episodes": int(len(same)),
            "so_rpy_success": {m: float(so[m].mean()) for m in spec.methods}}


def summarise(df: pd.DataFrame, spec, table: pd.DataFrame, ranks: dict, selection: pd.DataFrame) -> dict:
    """The named values of the findings (facts.json), but the check against the compare test sweep."""
    means = df.groupby(["plant", "method", "seed"])[list(RATES)].mean()
    facts: dict = {"methods": len(spec.methods), "seeds": len(SEEDS), "pairs": len(spec.methods) * len(SEEDS),
                   "budget": spec.selection.budget,
                   "fields_per_family": spec.test.fields, "families": len(spec.test.families),
                   "comparisons": len(table), "rank": ranks, "verdict_changes": verdict_changes(table)}
    for metric in RATES:
        m = means[metric].groupby(["plant", "method"]).mean()
        facts[metric] = {short(p): {k: float(m[(p, k)]) for k in spec.methods} for p in PLANTS}
    for against in ("basic", BASE):
        part = table[table["against"] == against]
        facts[f"all_seeds_vs_{against}"] = {short(p): {m: study.unanimous(g["verdict"]) for m, g in
                                                       part[part["plant"] == p].groupby("method", sort=False)}
                                            for p in PLANTS if p in set(part["plant"])}
    facts["protocol"] = protocol(spec)
    facts["no_estimator"] = no_estimator(df, spec)
    changes = facts["verdict_changes"]
    facts["method_changes"] = {m: sum(c.startswith(f"{m}/") for step in changes.values() for c in step["changes"])
                               for m in spec.methods if m != spec.baseline}
    facts["worse_than_on_double_integrator"] = {
        plant: sum(v == "worse" for v in verdicts.values())
        for plant, verdicts in facts[f"all_seeds_vs_{BASE}"].items()}
    facts["largest_change"] = {  # per ladder step, the largest change of a method's success [fraction]
        f"{short(plant)}/{short(other)}": max(abs(facts["success"][short(plant)][m] - facts["success"][short(other)][m])
                                              for m in spec.methods) for plant, other in LADDER}
    facts["ranking"] = {short(p): sorted(spec.methods, key=lambda m: -facts["success"][short(p)][m]) for p in PLANTS}
    facts["per_family"] = per_family(df, spec)
    facts["selection_spent"] = {m: {"episodes": int(g["episodes"].min()),
                                    "seconds": float(g["seconds"].mean())}
                                for m, g in selection.groupby("method", sort=False)}
    facts["chose_defaults"] = {m: int((g["chosen"] == "defaults").sum())
                               for m, g in selection.groupby("method", sort=False)}
    facts["flight_seconds"] = {short(p): {m: float(g["seconds"].iloc[0]) for m, g in
                                          df[df["plant"] == p].groupby("method", sort=False)} for p in PLANTS}
    return facts


def page(facts: dict, spec, table: pd.DataFrame) -> list[str]:
    """The results README's sections (after the title and the command)."""
    from jaxapf.stats import VERDICT_RULE

    plants = list(PLANTS)
    order = facts["ranking"][BASE]
    lines = ["The report in [`report/`](report/report.md) is the double integrator's compare test; the numbers of "
             "every plant are read from `outcomes.parquet` (one row per plant, method, selection and field, committed) "
             "and `comparisons.csv` (every paired comparison with its verdict); `facts.json` names them.", "",
             "Protocol (module docstring): study 11's nine methods, each selected on the scaled double integrator by "
             f"a random search of {facts['budget']} episodes per seed (seeds 1–3), then flown with its three "
             f"selections on the same {facts['fields_per_family']} held-out fields of each of the "
             f"{facts['families']} scaled families, on five plants. Verdicts on success, exact McNemar and TOST "
             f"within {100 * MARGIN:g} points, Holm over all {facts['comparisons']} comparisons ({VERDICT_RULE}). "
             "What was scaled: [`sweeps/crazyflie-scaled.toml`](../../../sweeps/crazyflie-scaled.toml).", "",
             "## Does the ranking carry?", "",
             "Spearman's ρ of the nine methods' pooled success (mean over the three selections) between two plants, "
             "95 % bootstrap interval over the fields (the three selections held fixed: it does not cover the "
             "selection's own randomness, which the seeds' ρ show), and ρ of each selection seed's gains alone:", "",
             "| step | what it adds | ρ | interval | seeds 1, 2, 3 | verdicts against `basic` changed |",
             "|---|---|---|---|---|---|"]
    for plant, other in LADDER:
        key = f"{short(plant)}/{short(other)}"
        r, c = facts["rank"][key], facts["verdict_changes"][key]
        lines.append(f"| {short(other)} → {short(plant)} | {PLANTS[plant]} | {r['rho']:.2f} | "
                     f"[{r['lo']:.2f}, {r['hi']:.2f}] | {', '.join(f'{x:.2f}' for x in r['per_seed'])} | "
                     f"{c['count']} of {c['of']} |")
    for plant in plants[2:4]:
        r = facts["rank"][f"{short(plant)}/{short(BASE)}"]
        lines.append(f"| {short(BASE)} → {short(plant)} | the ladder so far | {r['rho']:.2f} | "
                     f"[{r['lo']:.2f}, {r['hi']:.2f}] | {', '.join(f'{x:.2f}' for x in r['per_seed'])} | – |")
    lines += ["", "Verdicts against `basic` that changed along a step (method/seed: before → after):", ""]
    for key, c in facts["verdict_changes"].items():
        lines.append(f"- {key.replace('/', ' from ')}: " + ("; ".join(c["changes"]) if c["changes"] else "none"))
    lines += ["", "Differences to `basic` that change sign beyond the margin along a step, whatever their verdicts:",
              ""]
    for key, c in facts["verdict_changes"].items():
        lines.append(f"- {key.replace('/', ' from ')}: " + ("; ".join(
            f"{x['method']}/{x['seed']}: {100 * x['before']:+.1f} → {100 * x['after']:+.1f} points" for x in c["flips"])
            if c["flips"] else "none"))
    lines += ["", "Per method, how many of its twelve verdicts against `basic` (four steps, three seeds) changed: "
              + ", ".join(f"`{m}` {n}" for m, n in facts["method_changes"].items()) + ".", "",
              "## What each step does itself", "",
              "Each (method, selection) on a rung against itself on the rung below (so_rpy and first_principles: "
              "against the double integrator), on success, in the study's Holm family:", "",
              "| step | worse | better | equivalent | inconclusive |", "|---|---|---|---|---|"]
    for plant, other in LADDER:
        e = facts["verdict_changes"][f"{short(plant)}/{short(other)}"]["step_effect"]
        lines.append(f"| {short(other)} → {short(plant)} | {e['worse']} | {e['better']} | {e['equivalent']} | "
                     f"{e['inconclusive']} |")
    ne = facts["no_estimator"]
    lines += ["", "## Without the integral action (the estimator ablation)", "",
              f"On the double integrator {100 * ne['double_integrator_same']:.2f} % of the "
              f"{ne['double_integrator_episodes']:,} episodes end the same (success, collision) without it. On so_rpy "
              "without it, success, mean over the seeds: " + ", ".join(
                  f"`{m}` {100 * v:.1f} % (with it {100 * facts['success']['so_rpy'][m]:.1f} %)"
                  for m, v in ne["so_rpy_success"].items()) + "."]
    lines += ["", "## Per family", "",
              "ρ of the nine methods' success (mean over the seeds) on each family against the double integrator, "
              "and the leading method on the double integrator and with drag:", "",
              "| family | " + " | ".join(f"ρ {short(p)}" for p in plants[1:]) + " | leader, double_integrator "
              "| leader, so_rpy_rotor_drag |", "|---|" + "---|" * (len(plants) + 1)]
    for family, f in facts["per_family"].items():
        lines.append(f"| {family} | " + " | ".join(
            "–" if np.isnan(f["rho"][short(p)]) else f"{f['rho'][short(p)]:.2f}" for p in plants[1:])
            + f" | `{f['leader'][short(BASE)]}` | `{f['leader']['so_rpy_rotor_drag']}` |")
    lines += ["", "## Success [%] per plant", "",
              "Pooled over the families, mean over the three selections; the marks: each seed's verdict against "
              "`basic` of the same selection on the same plant (↑ better, ↓ worse, = equivalent, · inconclusive). "
              "Rows in the double integrator's order.", "",
              "| method | " + " | ".join(short(p) for p in plants) + " |", "|---|" + "---|" * len(plants)]
    vs = table[table["against"] == "basic"].sort_values("seed")
    for m in order:
        cells = []
        for p in plants:
            marks = "".join(MARK[v] for v in vs[(vs["plant"] == p) & (vs["method"] == m)]["verdict"])
            cells.append(f"{100 * facts['success'][short(p)][m]:.1f} {marks}".rstrip())
        lines.append(f"| `{m}` | " + " | ".join(cells) + " |")
    lines += ["", "## What the vehicle costs each method", "",
              "Success on each Crazyflie plant against the same selection on the double integrator, the verdict all "
              "three seeds give (`mixed` where they differ); collisions [%] and the mean largest tilt [deg]:", "",
              "| method | " + " | ".join(short(p) for p in plants[1:]) + " |", "|---|" + "---|" * (len(plants) - 1)]
    for m in order:
        cells = [f"{facts['all_seeds_vs_' + BASE][short(p)][m]} (coll. {100 * facts['collision'][short(p)][m]:.1f}, "
                 f"tilt {facts['max_tilt'][short(p)][m]:.1f})" for p in plants[1:]]
        lines.append(f"| `{m}` | " + " | ".join(cells) + " |")
    a = facts["agreement_with_compare"]
    lines += ["", "## Budgets and checks", "",
              "Selection (the same for every method): episodes and mean seconds per seed: " + "; ".join(
                  f"`{m}` {v['episodes']}, {v['seconds']:.1f} s" for m, v in facts["selection_spent"].items()) + ".",
              "", f"The double-integrator flights here reproduce the compare test sweep's outcome on {a['same']} of "
              f"{a['total']} episodes (the same fields and gains through another compiled program).", "",
              "Flight seconds per plant (three selections, all fields, compile included): " + "; ".join(
                  f"{short(p)} {sum(facts['flight_seconds'][short(p)].values()):.0f} s" for p in plants) + "."]
    return lines


def figure(facts: dict, spec, df: pd.DataFrame, path: pathlib.Path) -> None:
    """Each method's success along the plants (mean over the seeds, the seeds' range as a bar)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per_seed = df.groupby(["plant", "method", "seed"])["success"].mean()
    fig, ax = plt.subplots(figsize=(8.5, 4.6), dpi=110)
    x = np.arange(len(PLANTS))
    ladder = [p for p in PLANTS if p != "crazyflie_first_principles"]
    for i, method in enumerate(facts["ranking"][BASE]):
        seeds = np.array([[per_seed[(p, method, s)] for s in SEEDS] for p in PLANTS]) * 100
        offset = (i - len(spec.methods) / 2) * 0.03
        mean, lo, hi = seeds.mean(1), seeds.min(1), seeds.max(1)
        line = ax.errorbar(x[:len(ladder)] + offset, mean[:len(ladder)], yerr=[(mean - lo)[:len(ladder)],
                           (hi - mean)[:len(ladder)]], marker="o", ms=4, capsize=2, lw=1.2, label=method)
        ax.errorbar(x[len(ladder):] + offset, mean[len(ladder):], yerr=[(mean - lo)[len(ladder):],
                    (hi - mean)[len(ladder):]], marker="s", ms=4, capsize=2, lw=0, elinewidth=1.2,
                    color=line[0].get_color())
    ax.axvline(len(ladder) - 0.5, color="0.6", lw=0.8, ls="--")
    ax.set_xticks(x, [short(p) for p in PLANTS])
    ax.set_ylabel("held-out success [%]")
    ax.set_title("Study 18: the planners on the double integrator and the Crazyflie models", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=1, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


def main() -> None:
    from jaxapf.compare.spec import load_compare_spec

    args, out = study.begin(__doc__, STUDY)
    if args.facts_only or args.from_episodes:  # the committed outcomes hold every episode the study reads
        spec = load_compare_spec(study.ROOT / "sweeps" / SPEC)[0]
        df = pd.read_parquet(out / "outcomes.parquet")
        checked = json.loads((out / "agreement.json").read_text())
    else:
        spec, runs = study.run_compare_study(args, out, SPEC)
        df = fly(spec, out / "selection.csv")[list(KEPT)]
        df.to_parquet(out / "outcomes.parquet", index=False)
        checked = agreement(df, runs, spec)
        (out / "agreement.json").write_text(json.dumps(checked) + "\n")
    success = outcomes(df, spec)
    strata = df[(df["plant"] == BASE) & (df["method"] == spec.baseline) & (df["seed"] == SEEDS[0])].sort_values(
        ["family", "field"], kind="stable")["family"].to_numpy()
    table = comparisons(success, spec)
    facts = summarise(df, spec, table, rank_agreement(success, strata, args.resamples),
                      pd.read_csv(out / "selection.csv")) | {"agreement_with_compare": checked}
    study.write_facts(out, facts)
    if args.facts_only:
        return
    table.to_csv(out / "comparisons.csv", index=False)
    title = "Study 18 — do the planners' rankings carry to a vehicle identified from real flights?"
    figure(facts, spec, df, out / "ladder.png")
    command = "python analysis/identified_vehicle.py" + (" --from-episodes" if args.from_episodes else "")
    source = out / "outcomes.parquet" if args.from_episodes else runs / "test.parquet"
    study.write_readme(out, title, command, source,
                       ["\n".join(page(facts, spec, table))],
                       [("ladder.png", "Held-out success of every method on each plant, mean over the three selections "
                                       "(the bars: lowest and highest selection)")])
    print(f"wrote {out}/README.md")


if __name__ == "__main__":
    study.entry(main)

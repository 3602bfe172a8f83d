"""Study 13: does offset-free tracking, and a CBF robust to the push, rescue the stacks study 12 lost in wind?

Study 12 found every method short of its goal in a steady 6 m/s wind: the MPC plans without the
disturbance, so the UAV settles where the potential's pull balances the push. Here every method of
study 11 flies at the gains each of its three selections chose (seeds 1, 2, 3, tuned in calm air)
on study 12's held-out fields (48 per family of study 11's six, seed 200) in study 12's strongest
wind (6 m/s toward 90°, gusts of 3 m/s, τ = 2 s, drag 0.3 1/s), with and without the disturbance
observer (``estimator = "observer"`` at its default gain), and in calm air. For the two CBF stacks
the robust CBF (``robust_cbf``) is flown too: in a steady wind of 6 m/s with no gusts, whose push of
1.8 m/s² it is told (``cbf_margin = 1.8``), without an estimator; and in the gusty wind with the
observer and ``cbf_margin = 1.0``, the bound it is told on the estimate's error (not a guarantee:
gusts are Gaussian). The braking CBF (``braking_cbf``, a barrier that keeps the braking the box
allows in reserve) is flown told the steady push (δ = 1.8) and in calm air (δ = 0), its guarantee
checked episode by episode. Every method is also flown at its tuned best in the wind: the same protocol's
random search with selection in this wind, without the estimator
(``sweeps/planner-benchmark-wind.toml``) and with the observer
(``sweeps/planner-benchmark-wind-observer.toml``), three seeds each, flown in the world it was tuned
in. The integral action (``estimator = "integral"``) is tested against control theory
(tests/control/test_estimators.py), not flown here.

Each (method, selection seed, arm) is compared with the calm-air selection of the same seed in the
gusty wind without an estimator, paired on the fields: exact McNemar and TOST within the 2-point
margin of success, :func:`jaxapf.stats.decide`, the verdict function every study uses, with one declared
Holm family, every comparison of the study, each interval at the level that decided its verdict.

    python analysis/offset_free.py                     # ~20 min on 2 cores once the wind selections exist
    python analysis/offset_free.py --kept-selections   # at the committed selections in wind
"""

from __future__ import annotations

import json
import pathlib

import jax
import numpy as np
import pandas as pd
import robustness
import study

STUDY = "offset_free"
FIELDS = robustness.FIELDS  # per family, study 12's held-out fields
MARGIN = 0.02
GUSTY = {"wind_speed": 6.0, "wind_heading": 90.0, "gust_sigma": 3.0}
STEADY = {"wind_speed": 6.0, "wind_heading": 90.0, "gust_sigma": 0.0}
#: Where a selection's gains come from: study 11's (tuned in calm air), or the same protocol with selection
#: in this study's gusty wind, without and with the observer (``jaxapf compare``'s selections of the spec).
TUNED = {"calm": None, "wind": study.ROOT / "sweeps" / "planner-benchmark-wind.toml",
         "wind + observer": study.ROOT / "sweeps" / "planner-benchmark-wind-observer.toml"}
#: (arm, static settings on top of the method's, gains on top of its selection, the selection's TUNED
#: source); the first is the baseline.
ARMS = [("wind", {}, GUSTY, "calm"), ("wind + observer", {"estimator": "observer"}, GUSTY, "calm"),
        ("calm", {}, {}, "calm"), ("wind, tuned in wind", {}, GUSTY, "wind"),
        ("wind + observer, tuned in wind + observer", {"estimator": "observer"}, GUSTY, "wind + observer")]
#: Arms of the CBF stacks only: the robust CBF, told the push (steady wind) or the estimate's error.
ROBUST = [("steady wind, robust CBF δ = 1.8", {"filter": "robust_cbf"}, STEADY | {"cbf_margin": 1.8}, "calm"),
          ("wind + observer, robust CBF δ = 1.0", {"filter": "robust_cbf", "estimator": "observer"},
           GUSTY | {"cbf_margin": 1.0}, "calm"),
          ("steady wind, braking CBF δ = 1.8", {"filter": "braking_cbf"}, STEADY | {"cbf_margin": 1.8}, "calm"),
          ("calm, braking CBF δ = 0", {"filter": "braking_cbf"}, {"cbf_margin": 0.0}, "calm")]
#: Each arm's short name, its key in facts.json.
KEYS = {"wind": "wind", "wind + observer": "observer", "calm": "calm", "wind, tuned in wind": "tuned_wind",
        "wind + observer, tuned in wind + observer": "tuned_observer", ROBUST[0][0]: "robust_steady",
        ROBUST[1][0]: "robust_observer", ROBUST[2][0]: "braking_steady", ROBUST[3][0]: "braking_calm"}
#: The braking CBF's arms, whose guarantee is checked episode by episode (:func:`guarantee`).
BRAKING = [arm for arm, static, _, _ in ROBUST if static.get("filter") == "braking_cbf"]
METRICS = ("success", "collision", "stalled", "min_clearance", "final_distance", "cbf_infeasible_steps")


def selections() -> pd.DataFrame:
    """The selections tuned in wind: ``jaxapf compare``'s random search of each :data:`TUNED` spec, one
    per (method, seed), run here (and kept under ``runs/compare-NAME/selection``, reused when there)."""
    from jaxapf.compare.select import select
    from jaxapf.compare.spec import load_compare_spec

    rows = []
    for source, path in TUNED.items():
        if path is None:
            continue
        spec, _ = load_compare_spec(path)
        out = study.ROOT / "runs" / f"compare-{spec.name}" / "selection"
        out.parent.mkdir(parents=True, exist_ok=True)
        for seed in spec.selection.seeds:
            for method in spec.methods:
                chosen = select(spec, method, seed, out)
                rows.append({"tuned": source, "method": method, "seed": seed, "chosen": chosen.chosen,
                             "selection_success": chosen.selection_success,
                             **{g: chosen.gains[g] for g in spec.method_gains(method)}})
    return pd.DataFrame(rows)


def tuned_gains(tuned: pd.DataFrame, source: str, method: str, seed: int) -> dict[str, float]:
    """The gains ``method``'s selection with ``seed`` chose, tuned in ``source``."""
    if source == "calm":
        return robustness.tuned_gains(method, seed)
    row = tuned[(tuned["tuned"] == source) & (tuned["method"] == method) & (tuned["seed"] == seed)].iloc[0]
    return {g: float(v) for g, v in row.drop(["tuned", "method", "seed", "chosen", "selection_success"]).items()
            if pd.notna(v)}


def run(spec, tuned: pd.DataFrame, done: pd.DataFrame | None, arms: list | None = None) -> pd.DataFrame:
    """The rows of every (method, arm) not in ``done`` (a previous run's rows, kept), appended to it; only the
    CBF stacks' ``arms`` when given."""
    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.engine import evaluate

    groups = robustness.fields(spec, FIELDS)
    t_max = max(robustness.spec_t_max(spec, f) for f in spec.test.families)
    have = set() if done is None else set(zip(done["method"], done["arm"]))
    rows = [] if done is None else [done]
    for method in spec.methods:
        planner, _, safety = method.partition("+")
        base = SimConfig.from_flat(method=planner, filter=safety or "none", disturbance="wind", t_max=t_max)
        flown = (ARMS + ROBUST if arms is None else arms) if safety == "cbf" else (ARMS if arms is None else [])
        for arm, static, world, source in flown:
            if (method, arm) in have:
                continue
            batch = jax.tree_util.tree_map(lambda *x: np.asarray(x, np.float32), *[
                Gains(**(tuned_gains(tuned, source, method, s) | world)) for s in robustness.seeds()])
            for scenarios, family in groups:
                out = jax.device_get(evaluate(scenarios, batch, base.replace(**static), MPCConfig(), metrics=METRICS))
                for i, seed in enumerate(robustness.seeds()):
                    rows.append(pd.DataFrame({k: np.asarray(v[i]) for k, v in out.items()}).assign(
                        method=method, seed=seed, arm=arm, family=family,
                        field=[f"{f}/{j % FIELDS}" for j, f in enumerate(family)]))
        print(f"  {method}: done", flush=True)
    return pd.concat(rows, ignore_index=True)


#: The columns of an episode the study reads (kept in ``episodes.parquet``).
READ = ("method", "seed", "arm", "family", "field", "success", "collision", "stalled", "min_clearance",
        "final_distance", "cbf_infeasible_steps")


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    """Per (method, selection, arm) and per family (``all``: pooled): rates with Wilson intervals, the
    smallest clearance, the median final distance, the infeasible CBF steps, and the paired change in
    success against the same selection in the gusty wind without an estimator, with the verdict of
    :func:`jaxapf.stats.verdicts` over every such comparison of the study at once."""
    df = pd.concat([df, df.assign(family="all")], ignore_index=True)
    base = df[df["arm"] == ARMS[0][0]].set_index(["method", "seed", "family", "field"]).sort_index()["success"]
    out = []
    for (method, seed, arm, family), g in df.groupby(["method", "seed", "arm", "family"], sort=False):
        row = {"method": method, "seed": seed, "arm": arm, "family": family, "n": len(g)} | study.rates(g)
        row |= {"min_clearance": float(g["min_clearance"].min()), "final_distance": float(g["final_distance"].median()),
                "infeasible_steps": int(g["cbf_infeasible_steps"].sum())}
        if arm != ARMS[0][0]:
            then = base.loc[(method, seed, family)].loc[g["field"]].to_numpy(bool)
            row |= study.paired_success(g["success"].to_numpy(bool), then)
        out.append(row)
    return study.mark_verdicts(out, MARGIN)


def cell(rows: pd.DataFrame, key: str, scale: float = 100.0, digits: int = 1) -> str:
    values = rows.sort_values("seed")[key].to_numpy(np.float64) * scale
    return " / ".join(f"{v:.{digits}f}" for v in values)


MARK = {"better": "↑", "worse": "↓", "equivalent": "=", "inconclusive": "·"}


def success_table(summary: pd.DataFrame, family: str, arms: list[str]) -> list[str]:
    lines = ["| method | " + " | ".join(arms) + " |", "|---|" + "---|" * len(arms)]
    for method, g in summary[summary["family"] == family].groupby("method", sort=False):
        cells = []
        for arm in arms:
            rows = g[g["arm"] == arm].sort_values("seed")
            marks = "".join(MARK.get(v, "") for v in rows.get("verdict", pd.Series(dtype=object)) if isinstance(v, str))
            cells.append((cell(rows, "success") + (f" {marks}" if marks else "")) if len(rows) else "")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return lines


def unsafe_start(spec, margin: float) -> dict[str, bool]:
    """Per held-out field: whether some obstacle starts outside the braking CBF's safe set (``h_b < 0``
    with the UAV at rest at its start, ``δ = margin``, κ at its default), computed here in numpy from
    docs/spec.md §4: there the filter guarantees nothing from the first step on."""
    from jaxapf.config import SimConfig
    from jaxapf.control import FILTERS

    sim = SimConfig()
    kappa = next(g.default for g in FILTERS.get("braking_cbf").gains if g.name == "cbf_brake")
    beta, lam = kappa * (sim.vehicle.a_max - margin), 0.5 / sim.episode.dt
    out = {}
    for scenarios, family in robustness.fields(spec, FIELDS):
        obs = jax.device_get(scenarios.obstacles)
        keep = np.where(np.asarray(obs.cylinder)[..., None], [1.0, 1.0, 0.0], 1.0)
        r = keep * (np.asarray(scenarios.start)[:, None, :] - np.asarray(obs.position))
        w = keep * -np.asarray(obs.velocity)  # the UAV at rest
        dist = np.linalg.norm(r, axis=-1)
        d = dist - np.asarray(obs.radius) - sim.vehicle.r_uav - 0.5 * sim.vehicle.a_max * sim.episode.dt ** 2
        phi = np.where(lam * lam * d < 2 * beta, lam * d, np.sqrt(2 * beta * np.maximum(d, 0.0)))
        h = (r * w).sum(-1) / dist + phi
        bad = np.any(np.asarray(obs.valid) & (h < 0), axis=1)
        out |= {f"{f}/{j % FIELDS}": bool(v) for j, (f, v) in enumerate(zip(family, bad))}
    return out


def guarantee(df: pd.DataFrame, spec) -> dict:
    """Per braking arm and family: the episodes with negative clearance, how many of them started outside
    the safe set (:func:`unsafe_start`) or had a step at which the condition could not hold (both outside
    the guarantee), which of those two each such miss broke (a bad start; only an infeasible step), and the
    smallest clearance of the episodes inside it (its claim: >= 0)."""
    out = {}
    for arm in BRAKING:
        margin = next(world["cbf_margin"] for name, _, world, _ in ROBUST if name == arm)
        unsafe = unsafe_start(spec, margin)
        rows = df[df["arm"] == arm]
        out[arm] = {}
        for family, g in rows.groupby("family", sort=False):
            hit = g["min_clearance"] < 0
            start = g["field"].map(unsafe).to_numpy(bool)
            infeasible = g["cbf_infeasible_steps"].to_numpy() > 0
            inside = ~start & ~infeasible
            out[arm][family] = {"episodes": len(g), "negative": int(hit.sum()),
                                "negative_outside": int((hit & ~inside).sum()),
                                "negative_unsafe_start": int((hit & start).sum()),
                                "negative_infeasible_only": int((hit & ~start & infeasible).sum()),
                                "unsafe_start": int(start.sum()), "infeasible": int(infeasible.sum()),
                                "inside_min_clearance": float(g.loc[inside, "min_clearance"].min()) if inside.any()
                                else None}
    return out


def facts(summary: pd.DataFrame, tuned: pd.DataFrame, held: dict) -> dict:
    """The named values the findings state, from the study's tables (``summary.csv``, ``selection_wind.csv``)
    and the braking CBF's guarantee check ``held`` (:func:`guarantee`, which needs the episodes): the keys
    the results README reads and, per arm under its short name (:data:`KEYS`), the pooled success (per-method
    means and per selection), the verdicts (counted and per selection), median final distance and
    collisions; the CBF stacks' success on ``crossing_fast``, their clearance per family, and the
    guarantee check's counts with their totals."""
    from jaxapf.config import SimConfig

    arms = list(dict.fromkeys(summary["arm"]))
    pooled = summary[summary["family"] == "all"]
    cbf_stacks = summary[summary["method"].str.endswith("+cbf")]
    cbf = cbf_stacks[cbf_stacks["family"] == "crossing_fast"]
    robust = summary[(summary["arm"] == ROBUST[0][0]) & (summary["family"] != "all")]
    by_family = robust.groupby("family", sort=False)
    clear = by_family["min_clearance"].min()

    def count(verdicts: pd.Series) -> dict[str, int]:
        return {v: int((verdicts == v).sum()) for v in MARK}

    def per_arm(arm: str) -> dict:
        rows = pooled[pooled["arm"] == arm]
        by_method = rows.groupby("method", sort=False)
        mean = by_method["success"].mean()
        better = {m: int((v == "better").sum()) for m, v in by_method["verdict"]}
        out = {"selections": len(rows), "verdicts": count(rows["verdict"]),
               "verdicts_all": count(summary.loc[summary["arm"] == arm, "verdict"]),
               "verdict": {m: {str(r.seed): r.verdict for r in g.itertuples() if isinstance(r.verdict, str)}
                           for m, g in by_method},
               "better": better, "better_min": min(better.values()),
               "worse": {m: int((v == "worse").sum()) for m, v in by_method["verdict"]},
               **{x: {"selection_min": float(rows[x].min()), "selection_max": float(rows[x].max())}
                  for x in ("success", "final_distance", "collision")}}
        out["success"] |= {"method_mean": {m: float(v) for m, v in mean.items()},
                           "method_mean_min": float(mean.min()), "method_mean_max": float(mean.max())}
        return out

    def checked(families: dict) -> dict:
        inside = [v["inside_min_clearance"] for v in families.values() if v["inside_min_clearance"] is not None]
        return families | {"total": {k: sum(v[k] for v in families.values())
                                     for k in ("episodes", "negative", "negative_outside", "negative_unsafe_start",
                                               "negative_infeasible_only") if all(k in v for v in families.values())}
                           | {"inside_min_clearance": min(inside)}}

    return {
        "crossing_fast_cbf_observer_success_min": float(cbf[cbf["arm"] == "wind + observer"]["success"].min()),
        "crossing_fast_cbf_wind_success_max": float(cbf[cbf["arm"] == "wind"]["success"].max()),
        "crossing_fast_cbf_tuned_in_wind": [float(cbf[cbf["arm"] == "wind, tuned in wind"]["success"].min()),
                                            float(cbf[cbf["arm"] == "wind, tuned in wind"]["success"].max())],
        "pull_median": {"calm": float(np.median([robustness.flow_gain(m, s) for m in summary["method"].unique()
                                                for s in robustness.seeds()])),
                        **{src: float((g["eta"] * g["k_att"]).median()) for src, g in tuned.groupby("tuned")}},
        "crossing_fast_cbf_tuned_with_observer": [
            float(cbf[cbf["arm"] == "wind + observer, tuned in wind + observer"]["success"].min()),
            float(cbf[cbf["arm"] == "wind + observer, tuned in wind + observer"]["success"].max())],
        "robust_steady_min_clearance": {f: float(v) for f, v in clear.items()},
        "robust_steady_collision_max": {f: float(v) for f, v in by_family["collision"].max().items()},
        "robust_steady_infeasible": {f: int(v) for f, v in by_family["infeasible_steps"].sum().items()},
        "calm_cbf_min_clearance": {f: float(v) for f, v in summary[
            summary["method"].str.endswith("+cbf") & (summary["arm"] == "calm") & (summary["family"] != "all")
        ].groupby("family", sort=False)["min_clearance"].min().items()},
        "pooled_success_by_arm": {arm: [round(100 * float(v), 1) for v in
                                        pooled[pooled["arm"] == arm].groupby("method", sort=False)["success"].mean()]
                                  for arm in arms},
        "pooled_verdicts_by_arm": {arm: {k: int(v) for k, v in
                                         pooled[pooled["arm"] == arm]["verdict"].value_counts().items()}
                                   for arm in arms[1:]},
        "braking": held,
        "verdicts": {k: int(v) for k, v in summary["verdict"].value_counts().items()},
        "verdicts_pooled": {k: int(v) for k, v in pooled["verdict"].value_counts().items()},
        "setting": {"wind_speed": GUSTY["wind_speed"], "gust_sigma": GUSTY["gust_sigma"], "margin": MARGIN,
                    "fields_per_family": int(summary.loc[summary["family"] != "all", "n"].iloc[0]),
                    "seeds": int(summary["seed"].nunique()), "methods": int(summary["method"].nunique()),
                    "cbf_stacks": int(cbf_stacks["method"].nunique()),
                    "cbf_margin": {KEYS[name]: world["cbf_margin"] for name, _, world, _ in ROBUST},
                    "goal_tolerance": SimConfig().episode.r_goal},
        "comparisons": {"all": int(summary["verdict"].notna().sum()), "pooled": int(pooled["verdict"].notna().sum())},
        "verdict_counts": {"all": count(summary["verdict"]), "pooled": count(pooled["verdict"])},
        "arm": {KEYS[arm]: per_arm(arm) for arm in arms},
        "crossing_fast_cbf": {KEYS[arm]: {"min": float(g["success"].min()), "max": float(g["success"].max())}
                              for arm, g in cbf.groupby("arm", sort=False)},
        "cbf": {KEYS[arm]: {f: {"min_clearance": float(x["min_clearance"].min()),
                                "collision_max": float(x["collision"].max()),
                                "infeasible_steps": int(x["infeasible_steps"].sum())}
                            for f, x in g[g["family"] != "all"].groupby("family", sort=False)}
                for arm, g in cbf_stacks.groupby("arm", sort=False)},
        "guarantee": {KEYS[arm]: checked(families) for arm, families in held.items()},
    }


def write(summary: pd.DataFrame, tuned: pd.DataFrame, held: dict, out, command: str) -> dict:
    arms = list(dict.fromkeys(summary["arm"]))
    families = [f for f in dict.fromkeys(summary["family"]) if f != "all"]
    found = facts(summary, tuned, held)
    clear = pd.Series(found["robust_steady_min_clearance"])
    kept = [f for f, v in clear.items() if v >= 0]
    lost = [f for f, v in clear.items() if v < 0]
    lines = [f"# Study 13: offset-free tracking and the robust CBF in wind ({FIELDS} held-out fields per family)", "",
             f"`{command}` (" + __doc__.splitlines()[0].split(": ", 1)[1] + ")", "",
             "## Findings", "",
             f"- On `crossing_fast` the CBF stacks with the observer succeed on "
             f"{100 * found['crossing_fast_cbf_observer_success_min']:.1f} % of the fields or more (every selection "
             f"of both), against at most {100 * found['crossing_fast_cbf_wind_success_max']:.1f} % without an "
             "estimator in the same wind, calm-air selections both. Each at its tuned best in the wind the gap "
             f"narrows: without an estimator {100 * found['crossing_fast_cbf_tuned_in_wind'][0]:.1f}–"
             f"{100 * found['crossing_fast_cbf_tuned_in_wind'][1]:.1f} %, with the observer "
             f"{100 * found['crossing_fast_cbf_tuned_with_observer'][0]:.1f}–"
             f"{100 * found['crossing_fast_cbf_tuned_with_observer'][1]:.1f} % (the six selections of the two "
             "stacks). A selection tuned in the wind pulls harder toward the goal (median η·k_att over every "
             f"method's selections: {found['pull_median']['calm']:.2f} tuned in calm air, "
             f"{found['pull_median']['wind']:.2f} in the wind, {found['pull_median']['wind + observer']:.2f} in the "
             "wind with the observer); that the harder pull is what shrinks the offset is a hypothesis (the "
             "selections differ in every gain).",
             "- The robust CBF told the steady push (δ = 1.8 m/s², no estimator) keeps every episode clear on "
             + (", ".join(f"`{f}`" for f in kept) or "no family") + "; not on "
             + (", ".join(f"`{f}` (smallest clearance {clear[f]:.2f} m, "
                          f"{found['robust_steady_infeasible'][f]} infeasible steps)" for f in lost) or "none")
             + ". That the box cannot both absorb the push and brake for a moving obstacle there is a hypothesis; "
             "what the calm-air arm (the plain CBF, no wind) shows is that the filter misses these families "
             "before any wind (smallest clearance "
             + ", ".join(f"`{f}` {found['calm_cbf_min_clearance'][f]:.3f} m" for f in lost) + ").",
             *(f"- The braking CBF ({arm}, α and κ at their declared defaults): clearance >= 0 on every episode "
               "inside its guarantee, i.e. started in its safe set with every step feasible (smallest "
               + ", ".join(f"`{f}` {v['inside_min_clearance']:.3f} m" if v["inside_min_clearance"] is not None
                           else f"`{f}` none inside" for f, v in held[arm].items())
               + "); negative clearance on "
               + (", ".join(f"`{f}` {v['negative']} of {v['episodes']}" for f, v in held[arm].items() if v["negative"])
                  or "no episode")
               + (", each outside the guarantee" if all(v["negative"] == v["negative_outside"]
                                                         for v in held[arm].values()) else
                  ", some of them inside the guarantee: it fails")
               + ". Episodes started outside the safe set (an obstacle already too close for its closing speed): "
               + ", ".join(f"`{f}` {v['unsafe_start']}" for f, v in held[arm].items())
               + "; with an infeasible step (no acceleration in the box meeting every condition): "
               + ", ".join(f"`{f}` {v['infeasible']}" for f, v in held[arm].items())
               + (". Of the episodes with negative clearance, started outside the safe set: "
                  + ", ".join(f"`{f}` {v['negative_unsafe_start']} of {v['negative']}" for f, v in held[arm].items()
                              if v["negative"])
                  + "; inside it with only an infeasible step: "
                  + ", ".join(f"`{f}` {v['negative_infeasible_only']}" for f, v in held[arm].items() if v["negative"])
                  if all("negative_unsafe_start" in v for v in held[arm].values()) else "")
               + "." for arm in BRAKING),
             "- Pooled success, mean over the three selections, lowest to highest method: "
             + "; ".join(f"{arm} {min(v):.1f}–{max(v):.1f} %" for arm, v in found["pooled_success_by_arm"].items())
             + ". Pooled verdicts against the calm-air selections in the wind without an estimator: "
             + "; ".join(f"{arm}: " + ", ".join(f"{k} {n}" for k, n in v.items())
                         for arm, v in found["pooled_verdicts_by_arm"].items()) + ".",
             f"- Verdicts over all {sum(found['verdicts'].values())} comparisons of the study (Holm; pooled and per "
             "family): " + ", ".join(f"{k} {v}" for k, v in found["verdicts"].items()) + "; of the "
             f"{sum(found['verdicts_pooled'].values())} pooled ones: "
             + ", ".join(f"{k} {v}" for k, v in found["verdicts_pooled"].items()) + ".", "",
             "Protocol: " + " ".join(__doc__.split("\n\n")[1].split()), "",
             "## Success [%], all families pooled, per selection (seeds 1 / 2 / 3), and the verdicts against the "
             "same selection in the gusty wind without an estimator (↑ better, ↓ worse, = equivalent, · "
             "inconclusive)", ""]
    lines += success_table(summary, "all", arms)
    for family in families:
        lines += ["", f"## Success [%] on `{family}`", ""] + success_table(summary, family, arms)
    lines += ["", "## The CBF stacks: collision [%], smallest clearance [m], median final distance [m] and "
              "infeasible CBF steps per selection, per family", "",
              "| method | arm | family | collision | min clearance | final distance | infeasible steps |",
              "|---|---|---|---|---|---|---|"]
    cbf_rows = summary[summary["method"].str.endswith("+cbf") & (summary["family"] != "all")]
    for _, r in cbf_rows.groupby(["method", "arm", "family"], sort=False):
        lines.append(f"| {r['method'].iloc[0]} | {r['arm'].iloc[0]} | {r['family'].iloc[0]} | {cell(r, 'collision')} | "
                     f"{cell(r, 'min_clearance', 1.0, 2)} | {cell(r, 'final_distance', 1.0, 2)} | "
                     f"{' / '.join(str(int(v)) for v in r.sort_values('seed')['infeasible_steps'])} |")
    (out / "README.md").write_text("\n".join(lines) + "\n")
    study.write_facts(out, found)
    return found


def page_command(out: pathlib.Path, flag: str) -> str:
    """The command the committed page names (the run that flew its episodes), which the flags that only
    re-derive it keep; one line where the page names none."""
    from jaxapf.io.names import open_read
    from jaxapf.validation import ConfigError

    with open_read(study.kept(out, "README.md", flag), 1 << 24) as fh:
        lines = fh.read().decode().splitlines()
    found = lines[2].split("`")[1] if len(lines) > 2 and lines[2].startswith("`python analysis/") else None
    if found is None:
        raise ConfigError(f"{flag}: {out / 'README.md'} names no command on its third line; run the study "
                          "once without it")
    return found


def main() -> None:
    args, out = study.begin(__doc__, STUDY, {"--braking-only": "fly the braking CBF's arms again and rewrite their "
                                                              "guarantee check in facts.json (the other arms' "
                                                              "facts from the committed tables)"})
    # the command that flew the page's episodes: --facts-only and --braking-only keep the committed page's
    command = (page_command(out, "--facts-only" if args.facts_only else "--braking-only")
               if args.facts_only or args.braking_only else study.command_line("offset_free", args))
    if args.braking_only:  # the braking arms flown again for their guarantee check; the other facts recomputed
        from jaxapf.compare.spec import load_compare_spec

        spec, _ = load_compare_spec(robustness.SPEC)
        tuned = pd.read_csv(out / "selection_wind.csv")  # the braking arms fly study 11's calm-air selections
        held = guarantee(run(spec, tuned, None, arms=[a for a in ROBUST if a[0] in BRAKING]), spec)
        # the page and its facts, "braking" new; the tables the run's that made them
        write(pd.read_csv(out / "summary.csv"), tuned, held, out, command)
        return
    if args.facts_only:  # the page and its facts from the committed tables; the guarantee check ("braking")
        # from the kept episodes (a page committed before them: from its facts)
        from jaxapf.compare.spec import load_compare_spec

        if (out / "episodes.parquet").exists():
            held = guarantee(study.kept_rows(out), load_compare_spec(robustness.SPEC)[0])
        else:
            held = json.loads((out / "facts.json").read_text())["braking"]
        summary = study.rederive(pd.read_csv(out / "summary.csv"), MARGIN, change="success_change")
        summary.to_csv(out / "summary.csv", index=False)
        write(summary, pd.read_csv(out / "selection_wind.csv"), held, out, command)
        return
    from jaxapf.compare.spec import load_compare_spec

    spec, _ = load_compare_spec(robustness.SPEC)
    if args.from_episodes:  # the committed episodes and wind selections: nothing flown
        df, tuned = study.kept_rows(out), pd.read_csv(out / "selection_wind.csv")
    else:
        # git-ignored; a rerun only rewrites the tables
        data = study.ROOT / "runs" / f"offset-free-s{len(robustness.seeds())}-f{FIELDS}.parquet"
        if args.kept_selections:  # the committed selections in wind, not selected again
            tuned = study.kept_table(out, "selection_wind.csv", "--kept-selections")
        else:
            tuned = selections()
            tuned.to_csv(out / "selection_wind.csv", index=False)
        done = pd.read_parquet(data) if data.exists() else None
        df = run(spec, tuned, done)
        if done is None or len(df) > len(done):
            data.parent.mkdir(exist_ok=True)
            df.to_parquet(data, index=False)
        study.keep_rows(df, out, READ)
    summary = summarise(df)
    summary.to_csv(out / "summary.csv", index=False)
    found = write(summary, tuned, guarantee(df, spec), out, command)
    print(json.dumps(found, indent=1))


if __name__ == "__main__":
    study.entry(main)

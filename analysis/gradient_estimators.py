"""Study 14: how biased and how noisy is each gradient estimator of ``jaxapf tune`` on real closed-loop episodes?

Before an estimator is used in a tuning study its error is measured here, per episode, against a
reference for the quantity it estimates. Episodes: the first 8 training fields of each family of
``sweeps/tune-tiny.toml`` (crossing, trap; seed 0), flown at the spec's start gains. Reference: the
gradient of the smoothed loss ``J_σ`` (σ = 0.1 in θ) by the zeroth-order estimate with 4,096
antithetic pairs, whose own standard error is reported; beside it the exact pathwise gradient
``∇J(θ)`` of the unsmoothed loss. Each estimator (``pathwise``, and ``smoothed``, ``zeroth``,
``blend`` with 4 and 16 pairs) is drawn 100 times with independent keys: its bias (the distance of
its mean from the reference), its spread (root of the trace of its covariance) and its root mean
square error, each relative to the reference's norm, per episode and by the episode's outcome at the
start gains.

    python analysis/gradient_estimators.py      # ~10 min on 2 cores
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import study

STUDY = "gradient_estimators"
SPEC = study.ROOT / "sweeps" / "tune-tiny.toml"
FIELDS = 8  # per family
SIGMA = 0.1
REFERENCE_PAIRS = 4096
DRAWS = 100
ARMS = [("pathwise", 1), ("smoothed", 4), ("zeroth", 4), ("blend", 4), ("smoothed", 16), ("zeroth", 16),
        ("blend", 16)]


def episodes(spec):
    """The fixed episodes: fields 0..FIELDS-1 of each training family, padded to one obstacle count."""
    from jaxapf.tune.train import Tuner

    return Tuner(spec).fields(spec.train.seed, [FIELDS] * len(spec.train.families)), np.repeat(
        np.asarray(spec.train.families), FIELDS)


def draws(spec, estimator: str, samples: int, theta, scenarios, count: int, seed: int) -> np.ndarray:
    """``count`` independent estimates per episode, (episodes, count, gains)."""
    import dataclasses
    from functools import partial

    from jaxapf.tune.estimators import episode_gradient
    from jaxapf.tune.train import episode_loss

    case = dataclasses.replace(spec, train=dataclasses.replace(spec.train, estimator=estimator, samples=samples,
                                                                sigma=SIGMA))
    one = partial(episode_gradient, partial(episode_loss, spec=case), spec=case)
    names = spec.reparam.names

    @jax.jit
    def block(scenario, keys):
        grads = jax.vmap(lambda k: one(theta, scenario, k)[2])(keys)
        return jnp.stack([grads[n] for n in names], axis=-1)

    out = []
    n = scenarios.start.shape[0]
    for e in range(n):
        scenario = jax.tree_util.tree_map(lambda x, e=e: x[e], scenarios)
        keys = jax.random.split(jax.random.fold_in(jax.random.key(seed), e), count)
        out.append(np.concatenate([np.asarray(block(scenario, k)) for k in np.array_split(keys, max(count // 50, 1))]))
    return np.stack(out)


def facts(table: pd.DataFrame) -> dict:
    """The named values the findings state, from the per-episode table (``estimates.csv``): per estimator
    (``NAME/PAIRS``) the median bias, spread and RMSE over the episodes, the Monte-Carlo error of a mean of
    ``DRAWS`` draws (spread / sqrt(DRAWS)), the median RMSE by the episode's outcome and its range over the
    stalls, and the reference's standard error relative to its norm."""
    first = table[table["estimator"] == "pathwise"].sort_values("episode")
    arm = table["estimator"] + "/" + table["pairs"].astype(str)
    median = table.groupby(arm, sort=False)[["bias", "spread", "rmse"]].median()
    by_outcome = table.groupby([arm, "outcome"], sort=False)["rmse"].median()
    stalled = table[table["outcome"] == "stalled"].groupby(arm[table["outcome"] == "stalled"], sort=False)["rmse"]
    return {"episodes": len(first), "families": first["family"].nunique(), "fields_per_family": FIELDS,
            "outcomes": {k: int(v) for k, v in first["outcome"].value_counts().items()},
            "reference_relative_se_median": float((first["reference_se"] / first["reference_norm"]).median()),
            "reference_pairs": REFERENCE_PAIRS, "sigma": SIGMA, "draws": DRAWS,
            "finite_min": float(table["finite"].min()),
            "pairs": {a: int(p) for a, p in zip(arm, table["pairs"])},
            "rollouts": {a: int(r) for a, r in zip(arm, table["rollouts"])},
            "median": {a: {"bias": r.bias, "spread": r.spread, "rmse": r.rmse,
                           **({"mc_error": r.spread / np.sqrt(DRAWS)} if not a.startswith("pathwise") else {})}
                       for a, r in median.iterrows()},
            "median_by_outcome": {a: by_outcome[a].to_dict() for a in median.index},
            "stalled_rmse": {a: {"min": float(g.min()), "max": float(g.max())} for a, g in stalled}}


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    if args.facts_only:
        study.write_facts(out, facts(pd.read_csv(out / "estimates.csv")))
        return
    from jaxapf.tune.spec import load_tune_spec
    from jaxapf.tune.train import Tuner

    spec, _ = load_tune_spec(SPEC)
    scenarios, family = episodes(spec)
    theta = spec.reparam.theta(spec.init)
    outcome = Tuner(spec).report(scenarios, [spec.init])
    kind = np.where(outcome["success"][0], "success", np.where(outcome["collision"][0], "collision",
                                                               np.where(outcome["stalled"][0], "stalled", "timeout")))
    # the reference: zeroth order with many pairs, one draw of REFERENCE_PAIRS pairs in 16 blocks (for its error)
    blocks = draws(spec, "zeroth", REFERENCE_PAIRS // 16, theta, scenarios, 16, seed=10_000)
    reference = blocks.mean(axis=1)
    reference_se = np.sqrt(blocks.var(axis=1).sum(-1) / 16)
    exact = draws(spec, "pathwise", 1, theta, scenarios, 1, seed=0)[:, 0]
    rows = []
    for estimator, samples in ARMS:
        est = draws(spec, estimator, samples, theta, scenarios, DRAWS if estimator != "pathwise" else 1, seed=1)
        finite = np.all(np.isfinite(est), axis=-1)
        for e in range(est.shape[0]):
            good = est[e][finite[e]]
            norm = float(np.linalg.norm(reference[e]))
            mean = good.mean(axis=0)
            bias = float(np.linalg.norm(mean - reference[e]))
            spread = float(np.sqrt(good.var(axis=0).sum())) if len(good) > 1 else 0.0
            rows.append({"estimator": estimator, "pairs": samples if estimator != "pathwise" else 0,
                         "episode": e, "family": family[e], "outcome": kind[e],
                         "reference_norm": norm, "reference_se": float(reference_se[e]),
                         "pathwise_norm": float(np.linalg.norm(exact[e])),
                         "rollouts": 1 if estimator == "pathwise" else 2 * samples,
                         "finite": float(finite[e].mean()), "bias": bias / norm, "spread": spread / norm,
                         "rmse": float(np.sqrt(bias**2 + spread**2)) / norm})
        print(f"  {estimator} ({samples}): done", flush=True)
    table = pd.DataFrame(rows)
    table.to_csv(out / "estimates.csv", index=False)
    summary = (table.groupby(["estimator", "pairs"], sort=False)[["bias", "spread", "rmse"]].median()
               .reset_index())
    by_outcome = (table.groupby(["estimator", "pairs", "outcome"], sort=False)["rmse"].median().unstack("outcome")
                  .reset_index())
    found = facts(table)
    lines = [f"# Study 14: bias and spread of the gradient estimators ({len(family)} closed-loop episodes)", "",
             "`python analysis/gradient_estimators.py`", "",
             "Protocol: " + " ".join(__doc__.split("\n\n")[1].split()), "",
             "Outcomes at the start gains: " + ", ".join(f"{k} {v}" for k, v in found["outcomes"].items())
             + f". The reference's standard error is {100 * found['reference_relative_se_median']:.1f} % of its norm "
             "(median over the episodes).", "",
             "## Median over the episodes, relative to the reference's norm", "",
             "| estimator | pairs | rollouts per episode | bias | spread | RMSE |", "|---|---|---|---|---|---|"]
    for r in summary.itertuples():
        lines.append(f"| {r.estimator} | {r.pairs} | {1 if r.estimator == 'pathwise' else 2 * r.pairs} | "
                     f"{r.bias:.3f} | {r.spread:.3f} | {r.rmse:.3f} |")
    lines += ["", "## Median RMSE by the episode's outcome at the start gains", "",
              "| estimator | pairs | " + " | ".join(c for c in by_outcome.columns[2:]) + " |",
              "|---|---|" + "---|" * (len(by_outcome.columns) - 2)]
    for r in by_outcome.itertuples(index=False):
        lines.append(f"| {r[0]} | {r[1]} | " + " | ".join(f"{v:.3f}" for v in r[2:]) + " |")
    lines += ["", "## Per episode (estimates.csv)", "",
              "| episode | family | outcome | reference norm | its SE | pathwise norm |", "|---|---|---|---|---|---|"]
    first = table[table["estimator"] == "pathwise"]
    for r in first.itertuples():
        lines.append(f"| {r.episode} | {r.family} | {r.outcome} | {r.reference_norm:.3g} | {r.reference_se:.2g} | "
                     f"{r.pathwise_norm:.3g} |")
    print(json.dumps(study.write_results(out, lines, found), indent=1))


if __name__ == "__main__":
    study.entry(main)

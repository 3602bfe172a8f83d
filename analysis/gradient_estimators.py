"""Study 14: how biased and how noisy is each gradient estimator of ``jaxapf tune`` on real closed-loop episodes?

Before an estimator is used in a tuning study its error is measured here, per episode, against a
reference for the quantity it estimates. Episodes: the first 8 training fields of each family of
``sweeps/tune-tiny.toml`` (crossing, trap; seed 0), flown at the spec's start gains, and after them
the further fields (in order, up to field 200 of each family) that stall at the start gains, until
20 episodes stall. Reference: the gradient of the smoothed loss ``J_σ`` (σ = 0.1 in θ) by the
zeroth-order estimate in blocks of 256 antithetic pairs, at least 65,536 pairs and more until its
standard error is at most 1 % of its norm; beside it the exact pathwise gradient ``∇J(θ)`` of the
unsmoothed loss. Each estimator (``pathwise``, and ``smoothed``, ``zeroth``, ``blend`` with 4 and 16
pairs) is drawn 100 times with independent keys. Per episode, relative to the reference's norm: its
spread (root of the trace of its covariance), its bias (the distance of its mean from the reference
with the two Monte-Carlo errors taken out: ``b² = |mean − ref|² − spread²/100 − SE_ref²``, floored at
0) and its root mean square error ``√(b² + spread²)``. Medians over the episodes, overall and by the
episode's outcome at the start gains, with 95 % bootstrap intervals (percentile intervals of medians
over episodes resampled within their outcome, draws within their episode and the reference from its
standard error, moved by the Monte-Carlo noise the resampled draws add to the bias once more); two
estimators are told apart only where the interval of the difference of their medians excludes 0.

    python analysis/gradient_estimators.py      # ~80 min on 2 cores
    python analysis/gradient_estimators.py --facts-only   # the page and facts from draws.npz
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
FIELDS = 8  # per family, whatever their outcome
STALLS = 20  # episodes that stall, at least
SCAN = 200  # fields per family searched for them
SIGMA = 0.1
BLOCK = 256  # pairs in one block of the reference
REFERENCE_PAIRS = 65_536  # at least
REFERENCE_MAX = 262_144
REFERENCE_SE = 0.01  # its standard error relative to its norm, at most
DRAWS = 100
RESAMPLES = 2000
ARMS = [("pathwise", 1), ("smoothed", 4), ("zeroth", 4), ("blend", 4), ("smoothed", 16), ("zeroth", 16),
        ("blend", 16)]
GROUPS = ("all", "not stalled", "success", "timeout", "stalled")
# the comparisons the findings make: (arm, arm, group)
CONTRASTS = [("pathwise/0", "smoothed/16", "not stalled"), ("pathwise/0", "smoothed/16", "success"),
             ("pathwise/0", "smoothed/16", "timeout"), ("zeroth/16", "blend/16", "stalled"),
             ("zeroth/16", "blend/16", "not stalled"), ("pathwise/0", "zeroth/16", "stalled"),
             ("pathwise/0", "blend/16", "stalled")]


def arm_name(estimator: str, samples: int) -> str:
    return f"{estimator}/{0 if estimator == 'pathwise' else samples}"


def episodes(spec):
    """The fixed episodes (see the protocol) with their family, field index and outcome at the start gains."""
    from jaxapf.tune.train import Tuner

    tuner = Tuner(spec)
    picked = []
    for f in spec.train.families:
        scan = tuner.fields(spec.train.seed, [SCAN], [f])
        o = tuner.report(scan, [spec.init])
        kind = np.where(o["success"][0], "success", np.where(o["collision"][0], "collision",
                                                             np.where(o["stalled"][0], "stalled", "timeout")))
        picked.append((f, scan, kind))
    chosen = [(f, i) for f, _, _ in picked for i in range(FIELDS)]
    stalls = sum(kind[i] == "stalled" for f, _, kind in picked for i in range(FIELDS))
    for i in range(FIELDS, SCAN):  # further stalls, field by field, families in turn
        for f, _, kind in picked:
            if stalls < STALLS and kind[i] == "stalled":
                chosen.append((f, i))
                stalls += 1
    from jaxapf.tune.train import _concat

    by_family = {f: (scan, kind) for f, scan, kind in picked}
    scenarios = _concat([jax.tree_util.tree_map(lambda x, i=i, f=f: x[i:i + 1], by_family[f][0]) for f, i in chosen])
    return scenarios, pd.DataFrame({"family": [f for f, _ in chosen], "field": [i for _, i in chosen],
                                    "outcome": [by_family[f][1][i] for f, i in chosen]})


def estimator(spec, name: str, samples: int, theta):
    """One compiled estimate per key: ``(scenario, keys) -> (keys, gains)``."""
    import dataclasses
    from functools import partial

    from jaxapf.tune.estimators import episode_gradient
    from jaxapf.tune.train import episode_loss

    case = dataclasses.replace(spec, train=dataclasses.replace(spec.train, estimator=name, samples=samples,
                                                                sigma=SIGMA))
    one = partial(episode_gradient, partial(episode_loss, spec=case), spec=case)
    names = spec.reparam.names

    @jax.jit
    def block(scenario, keys):
        grads = jax.vmap(lambda k: one(theta, scenario, k)[2])(keys)
        return jnp.stack([grads[n] for n in names], axis=-1)

    return block


def draw(block, scenario, key, count: int, rollouts: int) -> np.ndarray:
    """``count`` estimates of ``rollouts`` rollouts each, (count, gains), about 8,192 rollouts a call."""
    keys = jax.random.split(key, count)
    per_call = max(1, 8192 // rollouts)
    return np.concatenate([np.asarray(block(scenario, keys[i:i + per_call])) for i in range(0, count, per_call)])


def reference(spec, theta, scenario, key):
    """Blocks of ``BLOCK`` pairs, at least ``REFERENCE_PAIRS`` and more until the standard error of their
    mean is at most ``REFERENCE_SE`` of its norm: (mean, variance of the mean per gain, pairs)."""
    block = reference.block
    blocks = [draw(block, scenario, jax.random.fold_in(key, 0), REFERENCE_PAIRS // BLOCK, 2 * BLOCK)]
    while True:
        b = np.concatenate(blocks)
        mean, var = b.mean(0), b.var(0, ddof=1) / len(b)
        if np.sqrt(var.sum()) <= REFERENCE_SE * np.linalg.norm(mean) or len(b) * BLOCK >= REFERENCE_MAX:
            return mean, var, len(b) * BLOCK
        blocks.append(draw(block, scenario, jax.random.fold_in(key, len(blocks)), REFERENCE_PAIRS // BLOCK // 4,
                           2 * BLOCK))


def episode_errors(draws: np.ndarray, ref: np.ndarray, ref_var: np.ndarray, debias: bool = True
                   ) -> tuple[float, float, float]:
    """(bias, spread, RMSE) of one episode's draws against the reference, relative to its norm; the
    bias with the Monte-Carlo errors of the draws' mean and of the reference taken out (``debias``)."""
    draws = np.asarray(draws, np.float64)  # a stall's smoothed estimates reach 1e19: their squares need float64
    ref, ref_var = np.asarray(ref, np.float64), np.asarray(ref_var, np.float64)
    draws = draws[np.all(np.isfinite(draws), axis=-1)]
    norm = np.linalg.norm(ref)
    n = len(draws)
    spread2 = draws.var(0, ddof=1).sum() if n > 1 else 0.0
    bias2 = float(((draws.mean(0) - ref) ** 2).sum())
    if debias:
        bias2 = max(bias2 - spread2 / n - ref_var.sum(), 0.0)
    return np.sqrt(bias2) / norm, np.sqrt(spread2) / norm, np.sqrt(bias2 + spread2) / norm


def group_mask(outcome: np.ndarray, group: str) -> np.ndarray:
    if group == "all":
        return np.ones(len(outcome), bool)
    if group == "not stalled":
        return outcome != "stalled"
    return outcome == group


def bootstrap(data, outcome: np.ndarray, seed: int = 0) -> dict:
    """Per group of episodes: the medians of every (arm, error), shape (arms, 3); ``RESAMPLES`` copies of
    them from episodes resampled within their outcome, draws within their episode and the reference from
    its error; and the same medians without the bias's Monte-Carlo correction (the resampled world's truth,
    which its resampled draws estimate with their noise added once more)."""
    rng = np.random.default_rng(seed)
    arms = list(data["arms"])
    n_ep = len(outcome)
    ref, ref_var = data["ref"], data["ref_var"]
    point = np.array([[episode_errors(data[a][e], ref[e], ref_var[e]) for e in range(n_ep)] for a in arms])
    raw = np.array([[episode_errors(data[a][e], ref[e], ref_var[e], debias=False) for e in range(n_ep)]
                    for a in arms])
    boot = np.empty((RESAMPLES,) + point.shape)
    for r in range(RESAMPLES):
        for e in range(n_ep):
            ref_r = ref[e] + rng.normal(size=ref[e].shape) * np.sqrt(ref_var[e])
            for k, a in enumerate(arms):
                d = data[a][e]
                boot[r, k, e] = episode_errors(d[rng.integers(len(d), size=len(d))], ref_r, ref_var[e])
    pick = np.empty((RESAMPLES, n_ep), int)  # episodes resampled within their outcome
    for kind in np.unique(outcome):
        idx = np.flatnonzero(outcome == kind)
        pick[:, idx] = rng.choice(idx, size=(RESAMPLES, len(idx)))
    boot = np.take_along_axis(boot, pick[:, None, :, None], axis=2)
    groups = {}
    for g in GROUPS:
        m = group_mask(outcome, g)
        if m.any():
            groups[g] = (np.median(point[:, m], axis=1), np.median(boot[:, :, m], axis=2),
                         np.median(raw[:, m], axis=1))
    return {"arms": arms, "groups": groups}


def interval_of(point, reps, raw) -> tuple:
    """The 95 % percentile interval of the resampled medians ``reps``, moved by ``raw − point``: the noise
    the resampled draws add once more to the bias (their centre is ``raw``, not ``point``)."""
    lo, hi = np.percentile(reps, [2.5, 97.5], axis=0)
    return lo - (raw - point), hi - (raw - point)


def facts(table: pd.DataFrame, data) -> dict:
    """The named values the findings state: per estimator (``NAME/PAIRS``) and group of episodes
    (all, not stalled, by outcome) the median bias, spread and RMSE with their 95 % intervals
    (``lo``/``hi``), the contrasts of the findings (difference of median RMSE, its interval, whether it
    excludes 0, and which is lower), and the reference's realised pairs and standard error."""
    first = table[table["estimator"] == "pathwise"].sort_values("episode")
    outcome = first["outcome"].to_numpy()
    boot = bootstrap(data, outcome)
    arms = boot["arms"]
    errors = {}
    for g, (point, reps, raw) in boot["groups"].items():
        for k, a in enumerate(arms):
            lo, hi = np.maximum(interval_of(point[k], reps[:, k], raw[k]), 0.0)
            errors.setdefault(a, {})[g] = {
                name: {"median": float(point[k, j]), "lo": float(lo[j]), "hi": float(hi[j])}
                for j, name in enumerate(("bias", "spread", "rmse"))}
    contrasts = {}
    for a, b, g in CONTRASTS:
        if g not in boot["groups"]:
            continue
        point, reps, raw = boot["groups"][g]
        i, j = arms.index(a), arms.index(b)
        lo, hi = interval_of(point[i, 2] - point[j, 2], reps[:, i, 2] - reps[:, j, 2], raw[i, 2] - raw[j, 2])
        separated = bool(lo > 0 or hi < 0)
        contrasts[f"{a} vs {b} ({g})"] = {
            "difference": float(point[i, 2] - point[j, 2]), "lo": float(lo), "hi": float(hi),
            "separated": separated,
            "lower": (a if point[i, 2] < point[j, 2] else b) if separated else "not separated"}
    rel_se = np.sqrt(np.asarray(data["ref_var"]).sum(-1)) / np.linalg.norm(data["ref"], axis=-1)
    arm = table["estimator"] + "/" + table["pairs"].astype(str)
    stalled = table[table["outcome"] == "stalled"].groupby(arm[table["outcome"] == "stalled"], sort=False)["rmse"]
    return {"episodes": len(first), "families": first["family"].nunique(), "fields_per_family": FIELDS,
            "stalls_sought": STALLS, "scan": SCAN,
            "episodes_by_family": {k: int(v) for k, v in first["family"].value_counts().items()},
            "outcomes": {k: int(v) for k, v in first["outcome"].value_counts().items()},
            "reference_relative_se_median": float(np.median(rel_se)),
            "reference_relative_se_max": float(rel_se.max()),
            "reference_pairs_min": int(first["reference_pairs"].min()),
            "reference_pairs_max": int(first["reference_pairs"].max()),
            "reference_block": BLOCK, "reference_se_target": REFERENCE_SE,
            "sigma": SIGMA, "draws": DRAWS, "resamples": RESAMPLES, "confidence": 0.95,
            "finite_min": float(table["finite"].min()),
            "pairs": {a: int(p) for a, p in zip(arm, table["pairs"])},
            "rollouts": {a: int(r) for a, r in zip(arm, table["rollouts"])},
            "errors": errors, "contrasts": contrasts,
            "stalled_rmse": {a: {"min": float(g.min()), "max": float(g.max())} for a, g in stalled}}


def load(out) -> dict:
    with np.load(out / "draws.npz") as f:
        data = {k: f[k] for k in f.files}
    data["arms"] = [arm_name(e, s) for e, s in ARMS]
    for a in data["arms"]:
        data[a] = data.pop("draws_" + a.replace("/", "_"))
    return data


def interval(e: dict, digits: int = 3) -> str:
    return f"{e['median']:.{digits}f} [{e['lo']:.{digits}f}, {e['hi']:.{digits}f}]"


def render(out) -> dict:
    """The page and facts.json from ``estimates.csv`` and ``draws.npz``."""
    table, data = pd.read_csv(out / "estimates.csv"), load(out)
    # the per-episode errors from the stored draws (one computation for the table and the bootstrap)
    for i, r in table.iterrows():
        a = arm_name(r["estimator"], int(r["pairs"]))
        e = int(r["episode"])
        table.loc[i, ["bias", "spread", "rmse"]] = episode_errors(data[a][e], data["ref"][e], data["ref_var"][e])
    table.to_csv(out / "estimates.csv", index=False)
    found = facts(table, data)
    lines = [f"# Study 14: bias and spread of the gradient estimators ({found['episodes']} closed-loop episodes)", "",
             "`python analysis/gradient_estimators.py`", "",
             "Protocol: " + " ".join(__doc__.split("\n\n")[1].split()), "",
             "Episodes by family: " + ", ".join(f"{k} {v}" for k, v in found["episodes_by_family"].items())
             + "; outcomes at the start gains: " + ", ".join(f"{k} {v}" for k, v in found["outcomes"].items())
             + f". The reference used {found['reference_pairs_min']:,} to {found['reference_pairs_max']:,} pairs; "
             f"its standard error is {100 * found['reference_relative_se_median']:.2f} % of its norm (median over "
             f"the episodes), {100 * found['reference_relative_se_max']:.2f} % at most.", ""]
    for g in GROUPS:
        if g not in found["errors"]["pathwise/0"]:
            continue
        lines += [f"## Median over the episodes ({g}), relative to the reference's norm, [95 % interval]", "",
                  "| estimator | pairs | rollouts per episode | bias | spread | RMSE |", "|---|---|---|---|---|---|"]
        for a in found["errors"]:
            e = found["errors"][a][g]
            lines.append(f"| {a.split('/')[0]} | {found['pairs'][a]} | {found['rollouts'][a]} | "
                         f"{interval(e['bias'])} | {interval(e['spread'])} | {interval(e['rmse'])} |")
        lines.append("")
    lines += ["## Contrasts (difference of median RMSE, first minus second)", "",
              "| contrast | difference | 95 % interval | lower error |", "|---|---|---|---|"]
    for k, c in found["contrasts"].items():
        lines.append(f"| {k} | {c['difference']:.3f} | [{c['lo']:.3f}, {c['hi']:.3f}] | {c['lower']} |")
    lines += ["", "## Per episode (estimates.csv)", "",
              "| episode | family | field | outcome | reference norm | its SE | pairs | pathwise norm |",
              "|---|---|---|---|---|---|---|---|"]
    first = table[table["estimator"] == "pathwise"]
    for r in first.itertuples():
        lines.append(f"| {r.episode} | {r.family} | {r.field} | {r.outcome} | {r.reference_norm:.3g} | "
                     f"{r.reference_se:.2g} | {r.reference_pairs:,} | {r.pathwise_norm:.3g} |")
    return study.write_results(out, lines, found)


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    if args.facts_only:
        render(out)
        return
    from jaxapf.tune.spec import load_tune_spec

    spec, _ = load_tune_spec(SPEC)
    scenarios, chosen = episodes(spec)
    theta = spec.reparam.theta(spec.init)
    n = len(chosen)
    print(f"  {n} episodes: " + ", ".join(f"{k} {v}" for k, v in chosen["outcome"].value_counts().items()), flush=True)
    reference.block = estimator(spec, "zeroth", BLOCK, theta)
    one = [jax.tree_util.tree_map(lambda x, e=e: x[e], scenarios) for e in range(n)]
    refs = [reference(spec, theta, s, jax.random.fold_in(jax.random.key(10_000), e)) for e, s in enumerate(one)]
    for e, r in enumerate(refs):
        print(f"  reference {e}: {r[2]:,} pairs, SE {np.sqrt(r[1].sum()) / np.linalg.norm(r[0]):.4f} of its norm",
              flush=True)
    exact = np.stack([draw(estimator(spec, "pathwise", 1, theta), s, jax.random.key(0), 1, 1)[0] for s in one])
    stored = {"ref": np.stack([r[0] for r in refs]), "ref_var": np.stack([r[1] for r in refs])}
    rows = []
    for name, samples in ARMS:
        block = estimator(spec, name, samples, theta)
        count = DRAWS if name != "pathwise" else 1
        est = np.stack([draw(block, s, jax.random.fold_in(jax.random.key(1), e), count, 2 * samples)
                        for e, s in enumerate(one)])
        finite = np.all(np.isfinite(est), axis=-1)
        stored["draws_" + arm_name(name, samples).replace("/", "_")] = np.where(finite[..., None], est, np.nan)
        for e in range(n):
            bias, spread, rmse = episode_errors(est[e][finite[e]], refs[e][0], refs[e][1])
            rows.append({"estimator": name, "pairs": samples if name != "pathwise" else 0, "episode": e,
                         "family": chosen["family"][e], "field": int(chosen["field"][e]),
                         "outcome": chosen["outcome"][e], "reference_norm": float(np.linalg.norm(refs[e][0])),
                         "reference_se": float(np.sqrt(refs[e][1].sum())), "reference_pairs": refs[e][2],
                         "pathwise_norm": float(np.linalg.norm(exact[e])),
                         "rollouts": 1 if name == "pathwise" else 2 * samples,
                         "finite": float(finite[e].mean()), "bias": bias, "spread": spread, "rmse": rmse})
        print(f"  {name} ({samples}): done", flush=True)
    pd.DataFrame(rows).to_csv(out / "estimates.csv", index=False)
    np.savez_compressed(out / "draws.npz", **{k: v.astype(np.float32) for k, v in stored.items()})
    print(json.dumps(render(out), indent=1))


if __name__ == "__main__":
    study.entry(main)

r"""The proof step of ``jaxapf tune``: tuned gains against the defaults and the black-box tuners.

Budgets
-------
Tuning used ``B = steps_run · fields_per_step · r + validations · validation.fields`` episode rollouts
(``r``: rollouts per training episode, 1 for the pathwise gradient, ``2 · train.samples`` for the
perturbed estimators).
Each search gets the same ``B``: its ``S`` settings (the grid product, or ``random_n``
random settings) are each flown on the first ``⌊B/S⌋`` training fields (seed ``train.seed``,
split over the training families as in a training step), and the setting with the highest success
rate wins (ties: the lowest mean surrogate loss). Gradients cost more than forward rollouts, so the
wall-clock times are reported next to the episode counts.

Test
----
The settings -- ``tuned`` (the gradient tuner's), ``default`` (:class:`~jaxapf.gains.Gains`, the
paper-style defaults) and each black-box tuner's of ``search.tuners`` (:mod:`jaxapf.tune.searches`) --
fly the same held-out fields (seed ``test.seed``, never seen in training or selection) of every test
family, so outcomes are paired. For each family and pooled over all of them: success and collision
rates with Wilson 95 % intervals, and McNemar (score) tests of each setting against ``default``
(Holm-adjusted over the whole table, per outcome).
"""

from __future__ import annotations

import itertools
import math
import pathlib
import time
from typing import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from .. import stats
from ..gains import Gains
from ..io.lock import write_atomic
from ..metrics import METRICS
from ..simulate.figures import plain_text
from .estimators import rollouts
from .objective import TERMS
from .spec import TuneSpec, split_count
from .train import TrainState, TuneError, Tuner

__all__ = [
    "candidates",
    "tuning_budget",
    "random_settings",
    "search_ranges",
    "select_best",
    "test_episodes",
    "comparison_table",
    "plot_training",
    "plot_test",
]

def tuning_budget(spec: TuneSpec, state: TrainState) -> dict[str, int]:
    """Episode rollouts the tuning used: training (steps × fields_per_step × the estimator's rollouts per
    episode, :func:`~jaxapf.tune.estimators.rollouts`) plus validation."""
    train = state.step * spec.train.fields_per_step * rollouts(spec)
    validation = state.validations * spec.validation.fields
    return {"gradient_steps": state.step, "training_episodes": train, "validations": state.validations,
            "validation_episodes": validation, "episodes": train + validation}


def search_ranges(spec: TuneSpec) -> dict[str, tuple[float, float, bool]]:
    """``{gain: (low, high, log)}``, the range every black-box tuner searches a tuned gain over:
    log-uniform in ``[x_0/r, x_0 r]`` around its start ``x_0`` (``r`` = ``search.random_range``);
    uniform over its tuning range where that is bounded (e.g. ``k`` in ``[0, 1]``); uniform from its
    lower end up ``r`` above it for a start at 0 (no log range around 0)."""
    b, rp = spec.search, spec.reparam
    out = {}
    for name in rp.names:
        low, high = rp.bounds(name)
        start = float(rp.base[name])
        if high is not None:
            out[name] = (float(low), float(high), False)
        elif start > 0:
            out[name] = (start / b.random_range, start * b.random_range, True)
        else:
            out[name] = (float(low), float(low) + b.random_range, False)
    return out


def random_settings(spec: TuneSpec) -> list[Gains]:
    """``random_n`` settings drawn from :func:`search_ranges` (log-uniform draws uniform in the log);
    untuned gains stay at their start values. Deterministic in ``random_seed``."""
    ranges = search_ranges(spec)
    rng = np.random.default_rng(spec.search.random_seed)
    settings = []
    for _ in range(spec.search.random_n):
        values = {}
        for name, (low, high, log) in ranges.items():
            values[name] = (math.exp(rng.uniform(math.log(low), math.log(high))) if log
                            else float(rng.uniform(low, high)))
        settings.append(spec.reparam.base.replace(**values))
    return settings


def select_best(tuner: Tuner, settings: Sequence[Gains], budget: int, label: str) -> dict:
    """The best of ``settings`` on ``⌊budget/len(settings)⌋`` training fields each (module docstring).

    Returns the winner's gains and index, its selection success rate and loss, the fields per
    setting, the episodes used and the wall-clock seconds.
    """
    spec = tuner.spec
    families = spec.train.families
    per = budget // len(settings)
    if per < len(families):
        raise TuneError(f"search: the {label} search has {len(settings)} settings but the tuning budget of "
                        f"{budget} episodes gives {per} fields per setting, fewer than the {len(families)} "
                        "training families; use fewer settings or more training steps")
    start = time.perf_counter()
    r = tuner.report(tuner.fields(spec.train.seed, split_count(per, len(families))), settings)
    success, loss = r["success"].mean(axis=1), r["loss"].mean(axis=1)
    best = int(np.lexsort((loss, -success))[0])
    return {"gains": settings[best], "index": best, "settings": len(settings), "fields_per_setting": per,
            "episodes": per * len(settings), "selection_success": float(success[best]),
            "selection_loss": float(loss[best]), "seconds": time.perf_counter() - start}


def test_episodes(tuner: Tuner, candidates: Mapping[str, Gains]) -> pd.DataFrame:
    """Every candidate on the test fields of every test family: one row per (family, field,
    setting) with the true metrics and the surrogate terms. Families with the same number of
    obstacle slots run in one batch."""
    spec = tuner.spec
    t = spec.test
    slots = lambda f: spec.family(f).max_obstacles  # noqa: E731
    frames = []
    for _, group in itertools.groupby(sorted(t.families, key=slots), key=slots):
        group = list(group)
        r = tuner.report(tuner.fields(t.seed, [t.fields] * len(group), families=group), list(candidates.values()))
        for g, setting in enumerate(candidates):
            frame = pd.DataFrame({k: r[k][g] for k in METRICS.names() + TERMS + ("loss",)})
            frame.insert(0, "setting", setting)
            frame.insert(0, "field", np.tile(np.arange(t.fields), len(group)))
            frame.insert(0, "family", np.repeat(group, t.fields))
            frames.append(frame)
    episodes = pd.concat(frames, ignore_index=True)
    episodes["family"] = pd.Categorical(episodes.family, list(t.families), ordered=True)
    episodes["setting"] = pd.Categorical(episodes.setting, list(candidates), ordered=True)
    return episodes.sort_values(["family", "setting", "field"], ignore_index=True)


def comparison_table(episodes: pd.DataFrame, families: Sequence[str]) -> pd.DataFrame:
    """Per family (and ``all``) and setting: rates with Wilson 95 % CIs, McNemar (score) tests against
    ``default`` (``b`` = pairs where the setting has the outcome and ``default`` not, ``c`` the
    reverse), Holm-adjusted p-values, and mean/median continuous metrics."""
    rows = []
    for family in list(families) + ["all"]:
        sub = episodes if family == "all" else episodes[episodes.family == family]
        ref = sub[sub.setting == "default"].sort_values(["family", "field"])
        for setting in episodes.setting.cat.categories:
            e = sub[sub.setting == setting].sort_values(["family", "field"])
            n = len(e)
            row = {"family": family, "setting": setting, "n": n}
            for outcome in ("success", "collision", "stalled"):
                r = stats.rate_row(e[outcome].to_numpy())
                row |= {outcome: r.rate, f"{outcome}_lo": r.lo, f"{outcome}_hi": r.hi}
            for outcome in ("success", "collision"):
                r = stats.RatePairs.of(e[outcome].to_numpy(bool), ref[outcome].to_numpy(bool))
                row |= {f"{outcome}_b": r.b, f"{outcome}_c": r.c,
                        f"{outcome}_p": math.nan if setting == "default" else r.p_difference()}
            row |= {"min_clearance": float(e.min_clearance.mean()), "time_to_goal": float(e.time_to_goal.median()),
                    "spl": float(e.spl.mean()), "loss": float(e.loss.mean())}
            row |= {t: float(e[t].mean()) for t in TERMS}
            rows.append(row)
    table = pd.DataFrame(rows)
    for outcome in ("success", "collision"):
        table[f"{outcome}_p_holm"] = stats.holm(table[f"{outcome}_p"].to_numpy())
    return table


@plain_text
def plot_training(history: pd.DataFrame, clip: float, path: pathlib.Path) -> None:
    """Training curves: loss (train, validation), each surrogate term, the gradient norms (per
    episode and of the step) with the fraction of episodes clipped, and the validation success and
    collision rates."""
    train = history[history.step > 0]
    val = history[np.isfinite(history.val_loss)]
    fig = Figure(figsize=(11, 7.5), layout="constrained")
    ax = fig.subplots(2, 2)
    ax[0, 0].plot(train.step, train.loss, lw=0.8, alpha=0.6, label="training batch")
    ax[0, 0].plot(val.step, val.val_loss, "o-", label="validation set")
    ax[0, 0].set(title="surrogate loss J", xlabel="step")
    for term in TERMS:
        (line,) = ax[0, 1].plot(train.step, train[term], lw=0.8, alpha=0.6, label=f"{term} (train)")
        ax[0, 1].plot(val.step, val[f"val_{term}"], "o-", color=line.get_color(), label=f"{term} (val)")
    ax[0, 1].set(title="surrogate terms (unweighted)", xlabel="step")
    ax[0, 1].set_yscale("symlog", linthresh=1e-2)
    ax[1, 0].plot(train.step, train.grad_norm_max, lw=0.6, color="C7", label="largest episode")
    ax[1, 0].plot(train.step, train.grad_norm_median, lw=0.8, color="C0", label="median episode")
    ax[1, 0].plot(train.step, train.grad_norm, lw=0.8, color="C2", label="step direction (episode-clipped)")
    ax[1, 0].axhline(clip, color="k", ls="--", lw=0.8, label=f"global clip = {clip:g}")
    ax[1, 0].set(title="gradient norms", xlabel="step", yscale="log")
    share = ax[1, 0].twinx()
    share.plot(train.step, train.clipped, color="C3", lw=0.8, alpha=0.7)
    share.set_ylabel("fraction of episodes clipped (red)", color="C3")
    share.set_ylim(-0.02, 1.02)
    ax[1, 1].plot(val.step, val.val_success, "o-", label="success")
    ax[1, 1].plot(val.step, val.val_collision, "s-", label="collision")
    ax[1, 1].set(title="validation rates", xlabel="step", ylim=(-0.02, 1.02))
    for a in ax.flat:
        a.legend(fontsize=7)
        a.grid(alpha=0.3)
    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=120))


@plain_text
def plot_test(table: pd.DataFrame, title: str, path: pathlib.Path) -> None:
    """Success and collision rates per test family and setting with Wilson 95 % intervals."""
    families = list(dict.fromkeys(table.family))
    fig = Figure(figsize=(max(7.0, 1.4 * len(families)), 6.5), layout="constrained")
    ax = fig.subplots(2, 1, sharex=True)
    names = list(dict.fromkeys(table.setting))
    width = 0.8 / len(names)
    x = np.arange(len(families))
    for i, setting in enumerate(names):
        rows = table[table.setting == setting].set_index("family").loc[families]
        for a, outcome in zip(ax, ("success", "collision")):
            err = np.vstack([rows[outcome] - rows[f"{outcome}_lo"], rows[f"{outcome}_hi"] - rows[outcome]])
            a.bar(x + (i - (len(names) - 1) / 2) * width, rows[outcome], width, yerr=err, capsize=2, label=setting)
    for a, outcome in zip(ax, ("success", "collision")):
        a.set(ylabel=f"{outcome} rate", ylim=(0, 1))
        a.grid(axis="y", alpha=0.3)
    ax[0].legend(ncol=len(names), fontsize=8)
    ax[0].set_title(title)
    ax[1].set_xticks(x, families)
    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=120))


def candidates(tuned: Gains, searched: Mapping[str, Gains]) -> dict[str, Gains]:
    """The settings of the test in table order: the gradient tuner's, the defaults, each search's."""
    return {"tuned": tuned, "default": Gains(), **searched}

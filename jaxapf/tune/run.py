"""``jaxapf tune SPEC.toml --out DIR``: learn the planner gains, then prove them on held-out fields.

Steps (each in its own module): validate the spec (:mod:`jaxapf.tune.spec`); train or resume
(:mod:`jaxapf.tune.train`); give each black-box tuner of ``search.tuners`` (grid, random, CMA-ES,
TPE: :mod:`jaxapf.tune.searches`) the same episode budget and test all settings on held-out fields
with paired statistics (:mod:`jaxapf.tune.proof`). ``DIR`` receives

- ``gains.toml``: the tuned gains as a ``[gains]`` table (``jaxapf simulate --gains``,
  ``jaxapf sweep --gains``, :func:`jaxapf.gains.load_gains`);
- ``summary.json``: resolved spec, spec file text, versions, the compared gain settings, training
  outcome, episode budgets and wall-clock times, the test table;
- ``history.csv``: one row per step (training batch loss, terms, gradient norm, learning rate) and
  the validation scores where validated (step 0 = the start gains);
- ``test_results.csv`` (the table), ``test_episodes.parquet`` (one row per test episode);
- ``training.png`` (training curves), ``test.png`` (test rates with 95 % intervals);
- ``checkpoint.npz``: the training state; rerunning the command resumes from it;
- ``searches.json``: the black-box tuners' results, reused by a rerun with the same spec;
  ``search-cmaes.json``, ``search-tpe.json``: their state while they run (a rerun resumes it).

The command holds ``DIR/.lock`` while it runs (one writer per folder, :mod:`jaxapf.io.lock`). Rerun
on a finished folder of the same spec, it prints the test table again and recomputes nothing;
interrupted (Ctrl-C), it keeps the checkpoint and finished searches for the rerun to resume.
"""

from __future__ import annotations

import io
import json
import math
import pathlib
import sys
import time
from typing import Any

import pandas as pd

from ..io.lock import write_atomic, writing
from ..io.names import read_own
from ..io.versions import versions
from ..text import csv_text
from .proof import candidates, comparison_table, plot_test, plot_training, test_episodes, tuning_budget
from .searches import SEARCHES
from .spec import TuneSpec, load_tune_spec
from .train import HISTORY_COLUMNS, TrainState, Tuner

__all__ = ["run_tune", "run_tune_spec", "write_gains_toml", "format_table", "finished_summary", "OUTPUTS"]


def _json_safe(x: Any) -> Any:
    """NaN/inf floats as ``null`` (strict JSON); containers converted recursively."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def write_gains_toml(path: pathlib.Path, gains: dict[str, float | list[float]], comment: str) -> None:
    """A ``[gains]`` TOML fragment (floats written with ``repr``: exact round trip; an array-valued gain as a
    list of them)."""
    lines = [f"# {line}" for line in comment.splitlines()] + ["[gains]"]
    lines += [f"{name} = {value!r}" for name, value in gains.items()]
    write_atomic(path, "\n".join(lines) + "\n")


def format_table(table: pd.DataFrame) -> str:
    """The test table as aligned text: rates with 95 % intervals, McNemar p vs default (Holm)."""
    w = max([len("setting"), *map(len, table["setting"])]) + 1
    out = [f"{'family':<10} {'setting':<{w}} {'n':>5}  {'success [95% CI]':<22} {'p_holm':>7}  "
           f"{'collision [95% CI]':<22} {'p_holm':>7}  {'loss':>7}"]
    for r in table.itertuples():
        rate = lambda o, r=r: f"{getattr(r, o):.3f} [{getattr(r, o + '_lo'):.3f}, {getattr(r, o + '_hi'):.3f}]"
        p = lambda o, r=r: "" if r.setting == "default" else f"{getattr(r, o + '_p_holm'):.3g}"
        out.append(f"{r.family:<10} {r.setting:<{w}} {r.n:>5}  {rate('success'):<22} {p('success'):>7}  "
                   f"{rate('collision'):<22} {p('collision'):>7}  {r.loss:>7.3f}")
    return "\n".join(out)


def _say(quiet: bool, message: str) -> None:
    if not quiet:
        print(message, file=sys.stderr, flush=True)


def _training_summary(spec: TuneSpec, state: TrainState) -> dict[str, Any]:
    return {"steps_run": state.step, "stopped_early": state.stopped, "best_step": state.best_step,
            "best_val_loss": state.best_val_loss, "validations": state.validations,
            "seconds": state.train_seconds, "remat": spec.train.remat}


def run_tune(spec_path: str | pathlib.Path, out: str | pathlib.Path | None = None, *,
             quiet: bool = False) -> dict[str, Any]:
    """Run the whole command on the spec file at ``spec_path`` (module docstring); returns the
    summary written to ``summary.json``. ``out`` defaults to ``runs/tune-NAME``.

    Raises :class:`~jaxapf.config.ConfigError` for a bad spec and
    :class:`~jaxapf.tune.train.TuneError` when training or a search cannot go on.
    """
    spec, text = load_tune_spec(spec_path)
    return run_tune_spec(spec, text, out if out is not None else pathlib.Path("runs") / f"tune-{spec.name}",
                         quiet=quiet)


#: The most a tune run's JSON record (``summary.json``, ``searches.json``) holds [bytes].
RECORD_BYTES = 64 * 2**20
#: Files a finished run leaves (``checkpoint.npz`` and ``searches.json`` come earlier).
OUTPUTS: tuple[str, ...] = ("gains.toml", "summary.json", "history.csv", "test_results.csv", "test_episodes.parquet",
                            "training.png", "test.png")


def finished_summary(out: pathlib.Path, digest: str) -> dict[str, Any] | None:
    """The summary of a finished run of the spec with ``digest`` in ``out``, None if there is none."""
    try:
        summary = json.loads(read_own(out / "summary.json", RECORD_BYTES))
    except (OSError, ValueError, RecursionError):  # missing, planted, too large (ConfigErrors), damaged
        return None
    if summary.get("spec_digest") != digest or not all((out / name).is_file() for name in OUTPUTS):
        return None
    return summary


def _search(tuner: Tuner, label: str, budget: int, out: pathlib.Path, digest: str) -> dict[str, Any]:
    """The black-box tuner ``label`` (:data:`~jaxapf.tune.searches.SEARCHES`), or its result stored in
    ``out/searches.json`` by a run of the same spec and budget."""
    path = out / "searches.json"
    try:
        stored = json.loads(read_own(path, RECORD_BYTES))
    except (OSError, ValueError, RecursionError):
        stored = {}
    if stored.get("spec_digest") != digest or stored.get("budget") != budget:
        stored = {"spec_digest": digest, "budget": budget}
    if label in stored:
        entry = stored[label]
        return entry | {"gains": tuner.spec.reparam.base.replace(**entry["gains"])}
    result = SEARCHES[label](tuner, budget, out, digest)
    stored[label] = result | {"gains": result["gains"].floats()}
    text = json.dumps(_json_safe(stored), indent=2) + "\n"
    write_atomic(path, lambda fh: fh.write(text.encode("utf-8")))
    return result


def run_tune_spec(spec: TuneSpec, text: str, out: str | pathlib.Path, *, quiet: bool = False) -> dict[str, Any]:
    """:func:`run_tune` on a validated spec; ``text`` is recorded as the spec file."""
    out = pathlib.Path(out)
    with writing(out, "the last training checkpoint and finished searches are kept"):
        return _run(spec, text, out, quiet)


def _run(spec: TuneSpec, text: str, out: pathlib.Path, quiet: bool) -> dict[str, Any]:
    """The body of :func:`run_tune_spec`, under the lock."""
    digest = spec.digest()
    done = finished_summary(out, digest)
    if done is not None:
        _say(quiet, f"{out} already holds this tuning run (finished); nothing to do. Its test table:")
        _say(quiet, format_table(pd.read_csv(io.BytesIO(read_own(out / "test_results.csv", RECORD_BYTES)))))
        return done
    tuner = Tuner(spec)

    state = tuner.train(out, quiet=quiet)
    history = pd.DataFrame(state.history, columns=list(HISTORY_COLUMNS))
    write_atomic(out / "history.csv", csv_text(history))
    plot_training(history, spec.train.clip, out / "training.png")
    tuned = spec.reparam.gains(state.best_theta)
    write_gains_toml(out / "gains.toml", tuned.floats(),
                     f"jaxapf tune {spec.name}: gains of the best validation loss "
                     f"({state.best_val_loss:.6g}, step {state.best_step} of {state.step}), trained by the spec "
                     f"below (digest {digest}):\n" + "\n".join(f"  {line}" for line in text.splitlines()))
    _say(quiet, f"trained {state.step} steps in {state.train_seconds:.1f} s; best validation loss "
                f"{state.best_val_loss:.4g} at step {state.best_step}")

    budget = tuning_budget(spec, state)
    searched = {}
    for label in spec.search.tuners:
        searched[label] = _search(tuner, label, budget["episodes"], out, digest)
        r = searched[label]
        _say(quiet, f"{label} search: {r['settings']} settings x {r['fields_per_setting']} fields "
                    f"in {r['seconds']:.1f} s")

    settings = candidates(tuned, {label: r["gains"] for label, r in searched.items()})
    start = time.perf_counter()
    episodes = test_episodes(tuner, settings)
    test_seconds = time.perf_counter() - start
    write_atomic(out / "test_episodes.parquet", lambda fh: episodes.to_parquet(fh, index=False))
    table = comparison_table(episodes, spec.test.families)
    write_atomic(out / "test_results.csv", csv_text(table))
    plot_test(table, f"{spec.name}: held-out test fields (seed {spec.test.seed})", out / "test.png")

    summary = {
        "name": spec.name,
        "spec": spec.as_dict(),
        "spec_digest": digest,
        "spec_file": text,
        "versions": versions(),
        "gains": {label: g.floats() for label, g in settings.items()},
        "training": _training_summary(spec, state),
        "budgets": {"tuning": budget | {"seconds": state.train_seconds},
                    **{name: {k: v for k, v in sel.items() if k != "gains"} for name, sel in searched.items()},
                    "test": {"episodes": len(episodes), "seconds": test_seconds}},
        "settings": list(settings),
        "test": table.to_dict(orient="records"),
    }
    write_atomic(out / "summary.json", json.dumps(_json_safe(summary), indent=2) + "\n")
    _say(quiet, format_table(table))
    _say(quiet, f"wrote {out}/: {', '.join(OUTPUTS)}, checkpoint.npz, searches.json")
    return summary

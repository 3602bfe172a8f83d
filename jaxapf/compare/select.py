r"""Selection: each method's gains, chosen on training fields under the same episode budget.

For one method and one selection seed ``s`` the searched gains (those of ``[selection] gains`` the
method reads) are chosen by

- ``random``: ``candidates`` settings, the method's defaults (:class:`~jaxapf.gains.Gains`) first,
  then ``candidates - 1`` draws from ``[selection.ranges]``. The draws are one matrix of uniforms
  from ``numpy.random.default_rng(s)``, a column per searched gain in declaration order, shared by
  every method: two methods try the same ``k_rep`` values. A gain a scorecard adds for one method
  (``added``) draws from its own stream, ``default_rng([s, crc32(name)])``, so the others draw what
  every member drew.
- ``grid``: the product of ``[selection.grid]`` over the gains the method reads (defaults first
  if they are a grid point, which they need not be).
- ``cmaes``, ``sep_cmaes``: ``jaxapf tune``'s CMA-ES (full or separable covariance,
  :mod:`jaxapf.tune.searches`) from the defaults, ``⌊budget / (λ m)⌋`` generations of ``λ``
  candidates on ``m`` fresh training fields each (``[selection.cmaes]``); the final mean is chosen
  (its selection success is not measured: that would cost episodes beyond the budget).
- ``gradient``: ``jaxapf tune``'s training (:class:`~jaxapf.tune.Tuner`) from the defaults, with
  as many steps as the budget pays for (``steps · fields_per_step`` training episodes plus
  ``(1 + ⌈steps / validate_every⌉) · validation_fields`` validation episodes); early stopping may
  spend less, and the episodes spent are reported.

A random or grid search flies every candidate on the same first ``⌊budget / candidates⌋``
training fields of seed ``s`` (split over ``[selection] families`` like a training step) and keeps
the highest success rate, ties broken by the lowest mean surrogate loss
(:func:`jaxapf.tune.proof.select_best`). Every method gets the same budget of episode rollouts; a
gradient episode costs several forward ones, so wall-clock seconds are reported too.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import pathlib
import time
import zlib
from typing import Any

import numpy as np

from ..config import SimConfig
from ..gains import Gains
from ..io.lock import write_atomic
from ..io.names import read_own, subfolder
from ..spec.scenario import spec_family_params
from ..tune import TuneError, Tuner, parse_tune_spec
from ..tune.proof import select_best, tuning_budget
from ..validation import ConfigError, first_line
from .spec import CompareSpec

__all__ = ["Selection", "tune_spec", "random_candidates", "grid_candidates", "gradient_steps", "select",
           "saved_selection", "spec_digest"]


@dataclasses.dataclass(frozen=True)
class Selection:
    """What one selection chose and what it cost."""

    method: str
    seed: int
    search: str
    gains: dict[str, float | list[float]]
    candidates: int
    fields_per_candidate: int
    episodes: int
    budget: int
    seconds: float
    selection_success: float
    selection_loss: float
    chosen: str  # "defaults", "candidate 7" or "step 40"

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def spec_digest(spec: CompareSpec) -> str:
    """sha256 of the spec's canonical JSON: a selection file belongs to one spec. Where the
    plugins were read from (``plugin_paths``) is not part of it, so a moved spec keeps its runs."""
    import hashlib

    fields = {k: v for k, v in dataclasses.asdict(spec).items()
              if k != "plugin_paths" and not (k == "gains" and not v)}  # no [gains]: the digest it always had
    fields["selection"] = {k: v for k, v in fields["selection"].items()
                           if not (k in ("searches", "cmaes", "added") and not v)}  # nor without per-method searches
    t_max = selection_t_max(spec)
    if t_max != SimConfig().episode.t_max:  # selections run at 60 s before the families' own length was read
        fields["selection_t_max"] = t_max
    text = json.dumps(fields, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def selection_t_max(spec: CompareSpec) -> float:
    """The episode length the selection flies: ``[sim] t_max`` if the spec sets it, else the longest of its
    training families' own (the test sweep flies each family its own, as every sweep does: the same length
    wherever the families agree)."""
    if "t_max" in spec.sim:
        return float(spec.sim["t_max"])
    return max(spec_family_params(f, spec.params.get(f, {})).t_max for f in spec.selection.families)


def _free_seed(start: int, taken: set[int]) -> int:
    seed = start % 2**32
    while seed in taken:
        seed = (seed + 1) % 2**32
    return seed


def tune_spec(spec: CompareSpec, method: str, seed: int, steps: int = 1):
    """The :class:`~jaxapf.tune.TuneSpec` of one selection: training families and seed, the
    method, the shared ``[sim]``, scenario parameters and objective, the method's searched gains.
    Its validation and (unused) test seeds avoid every selection seed and the test seed; ``steps``
    matters to a gradient search only (the others use the spec for its fields and scoring), and only
    the gradient and CMA-ES searches start from the defaults (``parse_tune_spec``'s ``start``)."""
    sel = spec.selection
    options = dict(sel.gradient)
    validation_fields = options.pop("validation_fields", 4 * len(sel.families))
    taken = set(sel.seeds) | {spec.test.seed}
    validation_seed = _free_seed(seed + 1_000_003, taken)
    test_seed = _free_seed(seed + 2_000_003, taken | {validation_seed})
    names = spec.method_gains(method)
    if not names:
        raise TuneError(f"{method} reads none of selection.gains ({', '.join(sel.gains)}): nothing to select")
    search, cmaes = sel.search_of(method), dict(sel.cmaes)
    black_box = {"tuners": [search], "cmaes_sigma": cmaes.get("sigma", 1.0), "popsize": cmaes.get("popsize", 0),
                 "fields_per_setting": cmaes.get("fields_per_candidate", 0)} if search in ("cmaes", "sep_cmaes") else {
                 "tuners": ["grid"]}  # (a tune spec names its black-box tuners; a compare selection runs one of them)
    data = {
        "name": f"{spec.name}-{method.replace('+', '-')}-seed{seed}",
        "plugins": list(spec.plugins),
        "train": {"families": list(sel.families), "seed": seed, "steps": steps,
                  "fields_per_step": options.pop("fields_per_step", max(16, len(sel.families))), **options},
        "validation": {"fields": validation_fields, "seed": validation_seed},
        "test": {"families": [sel.families[0]], "fields": 1, "seed": test_seed},
        "sim": {**{k: list(v) if isinstance(v, tuple) else v for k, v in spec.sim.items()}, **spec.settings(method),
                "t_max": selection_t_max(spec)},
        "scenario": {"params": {f: dict(p) for f, p in spec.params.items() if f in sel.families}},
        "objective": dict(spec.objective),
        "init": dict(spec.gains),
        "tune": {"params": list(names)},
        "search": black_box,
    }
    return parse_tune_spec(data, plugin_paths=spec.plugin_paths or None,
                           start=search in ("gradient", "cmaes", "sep_cmaes"))


def random_candidates(spec: CompareSpec, method: str, seed: int) -> list[Gains]:
    """The method's defaults, then ``candidates - 1`` draws (module docstring)."""
    sel = spec.selection
    names = set(spec.method_gains(method))
    shared = [(g, r) for g, r in sel.ranges if g not in sel.added]
    u = np.random.default_rng(seed).uniform(size=(sel.candidates - 1, len(shared)))
    columns = {g: u[:, i] for i, (g, _) in enumerate(shared)}
    columns |= {g: np.random.default_rng([seed, zlib.crc32(g.encode())]).uniform(size=sel.candidates - 1)
                for g in sel.added}
    base = fixed_gains(spec)
    return [base, *(base.replace(**{g: float(r.sample(np.array([columns[g][j]]))[0]) for g, r in sel.ranges
                                    if g in names}) for j in range(sel.candidates - 1))]


def fixed_gains(spec: CompareSpec) -> Gains:
    """The declared defaults with the spec's fixed ``[gains]``: every candidate's base."""
    return Gains().replace(**spec.gains)


def grid_candidates(spec: CompareSpec, method: str) -> list[Gains]:
    """The product of the grid over the gains the method reads (the defaults alone if none)."""
    names = set(spec.method_gains(method))
    axes = [(g, values) for g, values in spec.selection.grid if g in names]
    return [fixed_gains(spec).replace(**dict(zip([g for g, _ in axes], point)))
            for point in itertools.product(*(values for _, values in axes))]


def gradient_steps(budget: int, fields_per_step: int, validation_fields: int, validate_every: int) -> int:
    """Most training steps whose training and validation episodes fit in ``budget``."""
    steps = max(0, (budget - validation_fields) // fields_per_step)
    while steps > 0 and (steps * fields_per_step
                         + (1 + math.ceil(steps / validate_every)) * validation_fields) > budget:
        steps -= 1
    return steps


def restore(spec: CompareSpec, selections: list[Selection], out: pathlib.Path) -> None:
    """Write ``selections`` (e.g. a committed ``selection.csv``'s,
    :func:`~jaxapf.compare.protocol.read_selections`) into ``out`` as this spec's finished ones, so that a run
    flies its test at them instead of selecting again."""
    for s in selections:
        missing = [g for g in spec.method_gains(s.method) if g not in s.gains]
        if missing:
            raise ConfigError(f"the selection of {s.method} seed {s.seed} holds no {missing[0]} (a table keeps no "
                              "array-valued gain): select it again")
    out.parent.mkdir(parents=True, exist_ok=True)
    subfolder(out)
    digest = spec_digest(spec)
    for s in selections:
        _write_json(out / f"{s.method}-seed{s.seed}.json", {"spec_digest": digest, "selection": s.to_json()})


def _write_json(path: pathlib.Path, data: dict) -> None:
    text = json.dumps(data, indent=2, sort_keys=True) + "\n"
    write_atomic(path, lambda fh: fh.write(text.encode("utf-8")))


def saved_selection(spec: CompareSpec, method: str, seed: int, out: pathlib.Path) -> Selection | None:
    """The finished selection of ``method`` with seed ``seed`` of this spec in ``out``, or None."""
    path = out / f"{method}-seed{seed}.json"
    try:
        saved = json.loads(read_own(path, 2**20).decode("utf-8"))
        return Selection(**saved["selection"]) if saved.get("spec_digest") == spec_digest(spec) else None
    except FileNotFoundError:
        return None
    except (OSError, ValueError, RecursionError, KeyError, TypeError, AttributeError) as err:
        raise ConfigError(f"{path} is damaged ({type(err).__name__}: {first_line(err)}); remove it and rerun to "
                          "select that method again") from None


def select(spec: CompareSpec, method: str, seed: int, out: pathlib.Path, *, quiet: bool = True) -> Selection:
    """The selection of ``method`` with seed ``seed``; read from ``out/<method>-seed<seed>.json`` if a
    finished one of this spec is there, else run and written there (a gradient search checkpoints
    into ``out/<method>-seed<seed>/`` and resumes)."""
    subfolder(out)
    digest = spec_digest(spec)
    path = out / f"{method}-seed{seed}.json"
    saved = saved_selection(spec, method, seed, out)
    if saved is not None:
        return saved
    sel = spec.selection
    search = sel.search_of(method)
    start = time.perf_counter()
    if search == "gradient":
        probe = tune_spec(spec, method, seed, 1)
        t = probe.train
        steps = gradient_steps(sel.budget, t.fields_per_step, probe.validation.fields, t.validate_every)
        if steps < 1:
            raise TuneError(f"selection.budget = {sel.budget} pays for no gradient step of {t.fields_per_step} fields "
                            f"plus {probe.validation.fields} validation fields; raise the budget")
        tspec = tune_spec(spec, method, seed, steps)
        tuner = Tuner(tspec)
        subfolder(out / f"{method}-seed{seed}")
        state = tuner.train(out / f"{method}-seed{seed}", quiet=quiet)
        used = tuning_budget(tspec, state)
        best = next(r for r in state.history if r["step"] == state.best_step and math.isfinite(r["val_loss"]))
        result = Selection(method, seed, search, tspec.reparam.gains(state.best_theta).floats(), steps,
                           t.fields_per_step, used["episodes"], sel.budget, time.perf_counter() - start,
                           float(best["val_success"]), float(best["val_loss"]), f"step {state.best_step}")
    elif search in ("cmaes", "sep_cmaes"):
        from ..tune.searches import SEARCHES

        tuner = Tuner(tune_spec(spec, method, seed))
        subfolder(out / f"{method}-seed{seed}")
        r = SEARCHES[search](tuner, sel.budget, out / f"{method}-seed{seed}", digest)
        result = Selection(method, seed, search, r["gains"].floats(), r["settings"], r["fields_per_setting"],
                           r["episodes"], sel.budget, time.perf_counter() - start, math.nan,
                           r["last_generation_best_loss"], f"mean after {r['generations']} generations")
    else:
        tuner = Tuner(tune_spec(spec, method, seed))
        settings = random_candidates(spec, method, seed) if search == "random" else grid_candidates(spec, method)
        best = select_best(tuner, settings, sel.budget, search)
        chosen = "defaults" if best["gains"] == fixed_gains(spec) else f"candidate {best['index']}"
        result = Selection(method, seed, search, best["gains"].floats(), best["settings"],
                           best["fields_per_setting"], best["episodes"], sel.budget, time.perf_counter() - start,
                           best["selection_success"], best["selection_loss"], chosen)
    _write_json(path, {"spec_digest": digest, "selection": result.to_json()})
    return result

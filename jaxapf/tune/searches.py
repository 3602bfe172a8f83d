r"""The black-box tuners of ``jaxapf tune``, flown beside the gradient tuner under its episode budget.

Every tuner gets the ``B`` episode rollouts the gradient tuner used (:func:`~jaxapf.tune.proof.tuning_budget`)
and reports its wall-clock time; each result is a setting the held-out test then flies.

- ``grid``, ``random``: every setting on the same ``⌊B/S⌋`` training fields, the highest success wins
  (ties: the lowest surrogate loss); :func:`~jaxapf.tune.proof.select_best`.
- ``cmaes``: CMA-ES (Hansen, "The CMA evolution strategy: a tutorial", 2016; the ``cmaes`` library) on
  the gradient tuner's unconstrained coordinates ``θ`` (:class:`~jaxapf.tune.objective.Reparam`), its
  mean at the start gains and its step size ``search.cmaes_sigma``. Generation ``g`` flies its ``λ``
  candidates on the same fresh training fields (indices ``g·c_f …`` of seed ``train.seed``, ``m`` =
  ``search.fields_per_setting`` in all), ranked by their mean surrogate loss ``J``, the objective the
  gradient tuner descends; ``⌊B/(λm)⌋`` generations; the result is the final mean.
- ``sep_cmaes``: separable CMA-ES (Ros & Hansen, "A simple modification in CMA-ES achieving linear time
  and space complexity", PPSN 2008; the library's ``SepCMA``), the same protocol with a diagonal
  covariance: the black-box tuner for many coordinates (a learned weight's thousand parameters), where
  the full covariance's n² entries and n³ updates do not pay.
- ``tpe``: the tree-structured Parzen estimator (Bergstra et al., "Algorithms for hyper-parameter
  optimization", NeurIPS 2011; optuna's ``TPESampler``, multivariate) over the random search's ranges,
  trials asked ``search.tpe_batch`` at a time (constant liar), each batch on fresh training fields,
  value = mean ``J``; ``⌊B/m⌋`` trials in whole batches; the result is the trial of lowest ``J``.

Both save their state after every generation or batch (``search-NAME.json`` in the output folder, with
the spec's digest: data only, never a pickle) and resume from it exactly: CMA-ES stores its optimiser's
state (the library's ``__getstate__``, arrays as typed lists) and reseeds its sampling for generation
``g`` with ``(random_seed, g)`` (that state leaves its generator out), TPE replays its finished trials
into a new study and seeds batch ``b``'s sampler with ``(random_seed, b)``.
"""

from __future__ import annotations

import json
import math
import pathlib
import time
import warnings
from types import MappingProxyType
from typing import Any, Callable, Mapping

import jax.numpy as jnp
import numpy as np

from ..datatypes import Scenario
from ..io.lock import write_atomic
from ..io.names import read_own
from .proof import random_settings, search_ranges, select_best
from .spec import split_count
from .train import CheckpointError, TuneError, Tuner

__all__ = ["SEARCHES", "cmaes_search", "tpe_search", "round_fields"]


def round_fields(tuner: Tuner, index: int, fields: int) -> Scenario:
    """Round ``index``'s training fields: ``c_f`` per family (``fields`` split over the training
    families), indices ``index·c_f … (index+1)·c_f - 1`` of seed ``train.seed``."""
    spec = tuner.spec
    return tuner.fields(spec.train.seed, split_count(fields, len(spec.train.families)), block=index)


def _mean_loss(report: dict[str, np.ndarray]) -> np.ndarray:
    """Each setting's mean surrogate loss over its fields (a non-finite one ranks last)."""
    loss = report["loss"].mean(axis=1)
    return np.where(np.isfinite(loss), loss, np.finfo(np.float64).max)


class _Checkpoint:
    """A search's state in ``out/search-NAME.json``, belonging to one spec digest and budget: data only
    (numbers, lists, arrays as typed lists), so resuming from a folder never runs code it holds."""

    def __init__(self, out: pathlib.Path, name: str, digest: str) -> None:
        self.path, self.digest = out / f"search-{name}.json", digest

    def load(self, keys: Mapping[str, Any] = MappingProxyType({})) -> dict[str, Any] | None:
        """The saved state of this spec and budget, None if there is none; a saved state that lacks one of
        ``keys`` or holds it as another type than the one given is damaged
        (:class:`~jaxapf.tune.train.CheckpointError`)."""
        try:
            state = json.loads(read_own(self.path, STATE_BYTES), object_hook=_decode)
        except (OSError, ValueError, TypeError, KeyError, RecursionError):
            return None
        if not isinstance(state, dict) or state.get("digest") != self.digest:
            return None
        lacks = [k for k, kind in keys.items() if not isinstance(state.get(k), kind) or isinstance(state[k], bool)]
        if lacks:
            raise CheckpointError(f"{self.path} is damaged ({', '.join(lacks)} missing or of another type); remove "
                                  "it to run the search from the start")
        return state

    def save(self, state: dict[str, Any]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(state | {"digest": self.digest}, default=_encode)
        write_atomic(self.path, lambda fh: fh.write(text.encode()))


def _encode(value: Any) -> Any:
    """JSON for what a search's state holds besides plain numbers: numpy arrays and scalars (exact: a
    float's JSON is its shortest round-trip text) and CMA-ES's optimiser (its own state protocol)."""
    from cmaes import CMA, SepCMA

    if isinstance(value, np.ndarray):
        return {"__ndarray__": value.dtype.str, "shape": list(value.shape), "data": value.ravel().tolist()}
    if isinstance(value, np.generic):
        return {"__scalar__": value.dtype.str, "value": value.item()}
    if isinstance(value, (CMA, SepCMA)):
        return {_CMA_TAGS[type(value).__name__]: value.__getstate__()}
    raise TypeError(f"a search's state cannot hold {type(value).__name__}")


def _numeric(text: str) -> np.dtype:
    dtype = np.dtype(text)
    if dtype.kind not in "biuf":
        raise ValueError(f"not a numeric dtype: {text}")
    return dtype


def _decode(obj: dict[str, Any]) -> Any:
    """The inverse of :func:`_encode`, for one JSON object (inner objects first)."""
    if "__ndarray__" in obj:
        return np.asarray(obj["data"], dtype=_numeric(obj["__ndarray__"])).reshape(obj["shape"])
    if "__scalar__" in obj:
        return _numeric(obj["__scalar__"]).type(obj["value"])
    for name, tag in _CMA_TAGS.items():
        if tag in obj:
            import cmaes

            kind = getattr(cmaes, name)
            cma = kind.__new__(kind)
            cma.__setstate__(dict(obj[tag]))
            return cma
    return obj


#: The most a search's saved state holds [bytes] (an optimiser's state and its history of trials).
STATE_BYTES = 256 * 2**20
#: How a search's state names the ``cmaes`` library's optimisers.
_CMA_TAGS = {"CMA": "__cma__", "SepCMA": "__sepcma__"}


def _fields_per_setting(tuner: Tuner) -> int:
    return tuner.spec.search.fields_per_setting or tuner.spec.train.fields_per_step


def cmaes_search(tuner: Tuner, budget: int, out: pathlib.Path, digest: str, *, separable: bool = False
                 ) -> dict[str, Any]:
    """CMA-ES on ``θ`` (module docstring), with a diagonal covariance if ``separable``; resumes from
    ``out/search-cmaes.json`` (``search-sep_cmaes.json``)."""
    from cmaes import CMA, SepCMA

    kind, name = (SepCMA, "sep_cmaes") if separable else (CMA, "cmaes")
    spec, rp = tuner.spec, tuner.spec.reparam
    m = _fields_per_setting(tuner)
    start_theta = rp.theta(spec.init)
    checkpoint = _Checkpoint(out, name, f"{digest}/budget={budget}")
    state = checkpoint.load({"cma": kind, "generation": int, "seconds": float, "last": float}) or {
        "cma": kind(mean=rp.flatten(start_theta), sigma=spec.search.cmaes_sigma,
                    seed=spec.search.random_seed, population_size=spec.search.popsize or None),
        "generation": 0, "seconds": 0.0, "last": math.nan}
    cma = state["cma"]
    generations = budget // (cma.population_size * m)
    if generations < 1:
        raise TuneError(f"search: {'separable ' if separable else ''}CMA-ES needs {cma.population_size} candidates x "
                        f"{m} fields = "
                        f"{cma.population_size * m} episodes a generation, more than the tuning budget of {budget}; "
                        "lower search.popsize or search.fields_per_setting, or train longer")
    to_gains = lambda x: rp.gains(rp.unflatten(x, jnp.float32))  # noqa: E731
    while state["generation"] < generations:
        begin = time.perf_counter()
        cma.reseed_rng(spec.search.random_seed * 1_000_003 + state["generation"])  # the state drops the generator
        xs = [cma.ask() for _ in range(cma.population_size)]
        values = _mean_loss(tuner.report(round_fields(tuner, state["generation"], m), [to_gains(x) for x in xs]))
        cma.tell(list(zip(xs, values.tolist())))
        state |= {"generation": state["generation"] + 1, "last": float(values.min()),
                  "seconds": state["seconds"] + time.perf_counter() - begin}
        checkpoint.save(state)
    return {"gains": to_gains(cma.mean), "settings": generations * cma.population_size, "fields_per_setting": m,
            "episodes": generations * cma.population_size * m, "generations": generations,
            "population": cma.population_size, "last_generation_best_loss": state["last"], "seconds": state["seconds"]}


def tpe_search(tuner: Tuner, budget: int, out: pathlib.Path, digest: str) -> dict[str, Any]:
    """TPE over the random search's ranges (module docstring); resumes from ``out/search-tpe.json``."""
    import optuna
    from optuna.distributions import FloatDistribution

    spec = tuner.spec
    m, batch = _fields_per_setting(tuner), spec.search.tpe_batch
    batches = budget // (m * batch)
    if batches < 1:
        raise TuneError(f"search: TPE needs {batch} trials x {m} fields = {batch * m} episodes a batch, more than "
                        f"the tuning budget of {budget}; lower search.tpe_batch or search.fields_per_setting")
    space = {name: FloatDistribution(low, high, log=log) for name, (low, high, log) in search_ranges(spec).items()}
    checkpoint = _Checkpoint(out, "tpe", f"{digest}/budget={budget}")
    state = checkpoint.load({"trials": list, "seconds": float}) or {"trials": [], "seconds": 0.0}
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="minimize")
    study.add_trials([optuna.trial.create_trial(params=p, distributions=space, value=v) for p, v in state["trials"]])
    while len(state["trials"]) < batches * batch:
        begin = time.perf_counter()
        index = len(state["trials"]) // batch
        with warnings.catch_warnings():  # multivariate and constant_liar are marked experimental
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            study.sampler = optuna.samplers.TPESampler(seed=spec.search.random_seed * 1_000_003 + index,
                                                       multivariate=True, constant_liar=True)
        trials = [study.ask(space) for _ in range(batch)]
        settings = [spec.reparam.base.replace(**t.params) for t in trials]
        values = _mean_loss(tuner.report(round_fields(tuner, index, m), settings))
        for trial, value in zip(trials, values.tolist()):
            study.tell(trial, value)
            state["trials"].append((trial.params, value))
        state["seconds"] += time.perf_counter() - begin
        checkpoint.save(state)
    best = min(range(len(state["trials"])), key=lambda i: state["trials"][i][1])
    params, value = state["trials"][best]
    return {"gains": spec.reparam.base.replace(**params), "index": best, "settings": len(state["trials"]),
            "fields_per_setting": m, "episodes": len(state["trials"]) * m, "selection_loss": value,
            "seconds": state["seconds"]}


#: The black-box tuners by name: ``f(tuner, budget, out, digest) -> result`` (``gains``, ``episodes``,
#: ``seconds`` and what each reports of its selection).
SEARCHES: dict[str, Callable[[Tuner, int, pathlib.Path, str], dict[str, Any]]] = {
    "grid": lambda tuner, budget, out, digest: select_best(
        tuner, tuner.spec.search.grid_settings(tuner.spec.init), budget, "grid"),
    "random": lambda tuner, budget, out, digest: select_best(tuner, random_settings(tuner.spec), budget, "random"),
    "cmaes": cmaes_search,
    "sep_cmaes": lambda tuner, budget, out, digest: cmaes_search(tuner, budget, out, digest, separable=True),
    "tpe": tpe_search,
}


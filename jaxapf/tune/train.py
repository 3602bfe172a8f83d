r"""Training for ``jaxapf tune``: learn the planner gains by gradient descent through the closed loop.

One training step draws ``fields_per_step`` fresh fields from the training families (seed
``train.seed``; step ``s`` uses field indices ``s·c_f … (s+1)·c_f - 1`` of family ``f``, with the
step's ``c_f`` fields of each family fixed by :func:`~jaxapf.tune.spec.split_count`), rolls every
field out with the current gains, and takes one optimiser step on

.. math::  \nabla_\theta \frac{1}{B}\sum_{b=1}^{B} J\big(\mathrm{rollout}(\text{field}_b, g(\theta))\big)

(:mod:`jaxapf.tune.objective`: surrogate ``J``, reparametrisation ``g``). The gradient is exact
reverse-mode through the ``lax.scan`` over time, the APF reference flow (itself a scan over the
horizon of ``jax.grad`` forces) and the unrolled fixed-iteration FISTA (``clip``'s derivative at
the box). With ``train.remat`` every control step is rematerialised (:func:`jax.checkpoint`).

Every ``validate_every`` steps (and before the first) the gains are scored on a fixed validation
set (seed ``validation.seed``): surrogate loss and the true metrics of SPEC 6. The best
validation loss selects the final gains; ``patience`` validations without improvement stop early.
The whole state (θ, optimiser state, step, field counter, early-stopping state, history) is saved
atomically at every validation; rerunning the same command resumes from it, and because every
step is a deterministic function of that state, a resumed run ends bit-identical to an
uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import pathlib
import time
import zipfile
from functools import partial
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax import Array

from ..config import MPCConfig, SimConfig
from ..datatypes import Obstacles, Scenario
from ..engine import default_width, episode_index, program, rollout
from ..gains import Gains
from ..io.lock import write_atomic
from ..io.names import read_own
from ..metrics import METRICS, episode_metrics
from ..progress import Progress
from ..scenarios import FamilyParams, make_scenarios
from ..validation import ConfigError, first_line
from .estimators import episode_gradient
from .objective import TERMS, Objective, surrogate_loss, surrogate_terms
from .spec import TuneSpec, split_count

__all__ = [
    "CHECKPOINT",
    "TuneError",
    "TrainState",
    "Tuner",
    "episode_report",
    "episode_loss",
    "batch_gradient",
    "pad_obstacles",
    "family_fields",
    "stack_gains",
]

#: File name of the checkpoint inside the output folder.
CHECKPOINT = "checkpoint.npz"
_CHECKPOINT_FORMAT = "jaxapf.tune-checkpoint/1"


def _checkpoint_bytes(like: "TrainState") -> int:
    """The most a checkpoint of states shaped like ``like`` holds: its arrays (parameters, best parameters and
    the optimiser's state) at 8 bytes a number, twice over, and 1 MiB of metadata and archive headers."""
    numbers = sum(int(np.size(x)) for x in jax.tree_util.tree_leaves((like.theta, like.best_theta, like.opt_state)))
    return 16 * numbers + 2**20


#: Columns of a history row (NaN where a row has no value: validation columns between validations,
#: training columns of the step-0 validation).
HISTORY_COLUMNS: tuple[str, ...] = (
    ("step", "loss") + TERMS + ("grad_norm", "grad_norm_median", "grad_norm_max", "clipped", "learning_rate",
                                 "val_loss")
    + tuple(f"val_{t}" for t in TERMS) + ("val_success", "val_collision")
)


class TuneError(RuntimeError):
    """Training cannot go on (a non-finite loss, a budget too small for a search, a checkpoint
    from another spec)."""


class CheckpointError(TuneError, ConfigError):
    """A checkpoint in the output folder that cannot be resumed (damaged, or of another spec): bad input,
    said in one line with status 2 like any other."""


# --------------------------------------------------------------------------------------------
# fields and gains
# --------------------------------------------------------------------------------------------


def pad_obstacles(scenarios: Scenario, size: int) -> Scenario:
    """``scenarios`` (leading batch axis) with the obstacle set padded to ``size`` slots by invalid,
    parked slots (:meth:`Obstacles.empty`), so fields of different families stack in one batch.
    Padded slots contribute exactly nothing to potentials, metrics and the surrogate."""
    obs = scenarios.obstacles
    batch, extra = obs.radius.shape[0], size - obs.radius.shape[-1]
    empty = Obstacles.empty(extra, obs.position.dtype)
    grown = jax.tree_util.tree_map(
        lambda x, e: jnp.concatenate([x, jnp.broadcast_to(e, (batch,) + e.shape)], axis=1), obs, empty)
    return dataclasses.replace(scenarios, obstacles=grown)


#: Fields per :func:`~jaxapf.scenarios.make_scenarios` call: a fixed shape, so field generation
#: compiles once per family whatever the field counts are.
FIELD_BLOCK = 64


def family_fields(seed: int, params: FamilyParams, count: int, first: int = 0) -> Scenario:
    """Fields ``first … first+count-1`` of ``seed`` (exactly ``make_scenarios(seed, params, indices)``: a
    field does not depend on its batch), generated in blocks of :data:`FIELD_BLOCK`."""
    blocks = [make_scenarios(seed, params, np.arange(i, i + FIELD_BLOCK))
              for i in range(first, first + count, FIELD_BLOCK)]
    return jax.tree_util.tree_map(lambda *x: jnp.concatenate(x)[:count], *blocks)


def _take(tree: Any, index: np.ndarray) -> Any:
    """Rows ``index`` of every leaf of a batched pytree."""
    return jax.tree_util.tree_map(lambda x: x[index], tree)


def _concat(batches: Sequence[Scenario]) -> Scenario:
    size = max(b.obstacles.radius.shape[-1] for b in batches)
    return jax.tree_util.tree_map(lambda *x: jnp.concatenate(x), *(pad_obstacles(b, size) for b in batches))


def stack_gains(settings: Sequence[Gains]) -> Gains:
    """A batch (leading axis G) of gain settings (as :func:`~jaxapf.engine.evaluate` and
    :meth:`Tuner.report` take them)."""
    return jax.tree_util.tree_map(lambda *x: jnp.asarray(x, jnp.result_type(float)), *settings)


def episode_report(scenario: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, objective: Objective,
                   metrics: tuple[str, ...]) -> dict[str, Array]:
    """One rollout scored twice: the surrogate terms and loss (``loss``, :data:`TERMS`) and the
    true ``metrics`` (:func:`jaxapf.metrics.episode_metrics`)."""
    traj = rollout(scenario, gains, sim, mpc)
    terms = surrogate_terms(traj, scenario, sim, objective)
    return episode_metrics(traj, scenario, sim, metrics) | terms | {"loss": surrogate_loss(terms, objective)}


# --------------------------------------------------------------------------------------------
# state and checkpoint
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class TrainState:
    """Everything a resumed run needs. ``step`` = completed optimiser steps; the training-field
    counter of family ``f`` is ``step · c_f`` (the fields are a pure function of seed and index)."""

    theta: dict[str, Array]
    opt_state: Any
    best_theta: dict[str, Array]
    step: int = 0
    best_val_loss: float = math.inf
    best_step: int = 0
    bad_validations: int = 0
    stopped: bool = False
    train_seconds: float = 0.0
    history: list[dict[str, float]] = dataclasses.field(default_factory=list)

    @property
    def validations(self) -> int:
        return sum(1 for row in self.history if math.isfinite(row["val_loss"]))

    def save(self, path: pathlib.Path, digest: str, next_fields: dict[str, int]) -> None:
        """Write atomically (:func:`jaxapf.io.lock.write_atomic`)."""
        meta = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name not in ("theta", "opt_state", "best_theta")}
        meta |= {"format": _CHECKPOINT_FORMAT, "spec_digest": digest,
                 "rng": {"kind": "counter", "next_train_field": next_fields}}
        arrays = {f"theta/{k}": np.asarray(v) for k, v in self.theta.items()}
        arrays |= {f"best_theta/{k}": np.asarray(v) for k, v in self.best_theta.items()}
        arrays |= {f"opt/{i}": np.asarray(x) for i, x in enumerate(jax.tree_util.tree_leaves(self.opt_state))}
        write_atomic(path, lambda fh: np.savez(fh, meta=np.asarray(json.dumps(meta)), **arrays))

    @classmethod
    def load(cls, path: pathlib.Path, digest: str, like: "TrainState") -> "TrainState":
        """The state saved at ``path``; ``like`` (a fresh state) gives the pytree structure."""
        try:
            return cls._read(path, digest, like)
        except TuneError:
            raise
        except (OSError, ValueError, KeyError, TypeError, RecursionError, zipfile.BadZipFile) as err:
            raise CheckpointError(f"{path} is damaged ({type(err).__name__}: {first_line(err)}); remove it to train "
                                  "from the start") from None

    @classmethod
    def _read(cls, path: pathlib.Path, digest: str, like: "TrainState") -> "TrainState":
        with np.load(io.BytesIO(read_own(path, _checkpoint_bytes(like))), allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            if meta.get("format") != _CHECKPOINT_FORMAT or meta.get("spec_digest") != digest:
                raise CheckpointError(f"{path} belongs to a different spec; use another --out or delete it")
            theta = {k: jnp.asarray(data[f"theta/{k}"]) for k in like.theta}
            best = {k: jnp.asarray(data[f"best_theta/{k}"]) for k in like.theta}
            leaves, treedef = jax.tree_util.tree_flatten(like.opt_state)
            opt_state = jax.tree_util.tree_unflatten(treedef, [jnp.asarray(data[f"opt/{i}"])
                                                               for i in range(len(leaves))])
        fields = {f.name: meta[f.name] for f in dataclasses.fields(cls)
                  if f.name not in ("theta", "opt_state", "best_theta")}
        for name, kind in (("step", int), ("best_step", int), ("bad_validations", int), ("stopped", bool),
                           ("best_val_loss", (int, float)), ("train_seconds", (int, float)), ("history", list)):
            if not isinstance(fields[name], kind) or (kind is int and isinstance(fields[name], bool)):
                raise TypeError(f"{name} is {type(fields[name]).__name__}")
        for row in fields["history"]:
            if not isinstance(row, dict) or any(not isinstance(row.get(k), (int, float)) for k in HISTORY_COLUMNS):
                raise KeyError(f"a history row lacks one of {', '.join(HISTORY_COLUMNS)}")
        return cls(theta=theta, opt_state=opt_state, best_theta=best, **fields)


# --------------------------------------------------------------------------------------------
# compiled functions (module level, static spec: compiled once per spec and shape, shared by
# every Tuner of the same spec)
# --------------------------------------------------------------------------------------------


def episode_loss(theta: dict[str, Array], scenario: Scenario, spec: TuneSpec) -> tuple[Array, dict[str, Array]]:
    """Surrogate loss ``J`` (and its terms) of one training episode flown with ``g(θ)``."""
    traj = rollout(scenario, spec.reparam.gains(theta), spec.sim, spec.mpc, remat=spec.train.remat)
    terms = surrogate_terms(traj, scenario, spec.sim, spec.objective)
    return surrogate_loss(terms, spec.objective), terms


def batch_gradient(theta: dict[str, Array], batch: Scenario, spec: TuneSpec, key: Array | None = None
                   ) -> tuple[dict[str, Array], dict[str, Array]]:
    r"""The update direction of one batch (leading axis B on every leaf) and its logs.

    With per-episode gradients ``∇_b`` (:func:`~jaxapf.tune.estimators.episode_gradient` by
    ``train.estimator``; ``key`` draws the perturbations of the perturbed estimators) the direction is

    .. math:: d = \frac1B \sum_{b:\ \lVert\nabla_b\rVert < \infty}
              \nabla_b \min\big(1, c_e / \lVert\nabla_b\rVert\big)

    (``c_e`` = ``train.episode_clip``; ``inf`` keeps every finite gradient as it is). Closed-loop
    gradients explode in chaotic episodes -- a stall near an unstable equilibrium gives norms of
    10⁴ and far beyond (10²⁴ measured) next to the O(0.1–1) of a clean flight, and float32 may
    overflow to inf -- so one such
    episode would otherwise set the direction of the whole step. Logs: mean loss and terms,
    ``grad_norm`` = ``|d|`` (what the global clip then sees), the median and the largest
    per-episode norm, and ``clipped`` = fraction of episodes scaled down or dropped (non-finite).
    """
    size = batch.start.shape[0]
    keys = jax.random.split(jax.random.key(0) if key is None else key, size)
    estimate = partial(episode_gradient, partial(episode_loss, spec=spec), spec=spec)
    loss, terms, grads = jax.vmap(estimate, in_axes=(None, 0, 0))(theta, batch, keys)
    norms = jnp.sqrt(sum(jnp.sum(jnp.reshape(g * g, (size, -1)), axis=1) for g in grads.values()))
    finite = jnp.isfinite(norms)
    scale = jnp.where(finite, jnp.minimum(1.0, spec.train.episode_clip / jnp.where(finite, norms, 1.0)), 0.0)
    each = lambda x, g: jnp.reshape(x, (size,) + (1,) * (g.ndim - 1))  # noqa: E731  (B,) against g (B, ...)
    direction = {k: jnp.mean(jnp.where(each(finite, g), g, 0.0) * each(scale, g), axis=0) for k, g in grads.items()}
    logs = {"loss": jnp.mean(loss), **{k: jnp.mean(v) for k, v in terms.items()},
            "grad_norm": optax.tree.norm(direction), "grad_norm_median": jnp.median(norms),
            "grad_norm_max": jnp.max(norms), "clipped": jnp.mean(scale < 1.0)}
    return direction, logs


@program(static_argnames="spec")
def _train_step(theta: dict[str, Array], opt_state: Any, batch: Scenario, step: Array, spec: TuneSpec):
    """One optimiser step (clipping by global norm, then the optimiser of the spec); ``step`` keys the
    perturbations of the perturbed gradient estimators (``(train.seed, step)``)."""
    key = jax.random.fold_in(jax.random.key(spec.train.seed), step)
    direction, logs = batch_gradient(theta, batch, spec, key)
    updates, opt_state = spec.optimizer().update(direction, opt_state, theta)
    return optax.apply_updates(theta, updates), opt_state, logs


@program(static_argnames=("sim", "mpc", "objective", "metrics"))
def _report_batch(scenarios: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, objective: Objective,
                  metrics: tuple[str, ...]):
    """:func:`episode_report` of paired (field, gains) episodes (leading axis: the batch)."""
    return jax.vmap(partial(episode_report, sim=sim, mpc=mpc, objective=objective, metrics=metrics))(scenarios, gains)


# --------------------------------------------------------------------------------------------
# the tuner
# --------------------------------------------------------------------------------------------


class Tuner:
    """Fields, training and scoring for one :class:`~jaxapf.tune.spec.TuneSpec`."""

    def __init__(self, spec: TuneSpec) -> None:
        self.spec = spec
        self.schedule = spec.schedule()

    # --- fields --------------------------------------------------------------------------

    def fields(self, seed: int, counts: Sequence[int], families: Sequence[str] | None = None, block: int = 0
               ) -> Scenario:
        """Fields ``block·c_f … (block+1)·c_f - 1`` of every family ``f`` (default: the training families;
        ``c_f`` = its count; block 0: the first ones), padded to a common obstacle count and concatenated."""
        families = families or self.spec.train.families
        return _concat([family_fields(seed, self.spec.family(f), c, block * c)
                        for f, c in zip(families, counts) if c > 0])

    def step_counts(self) -> tuple[int, ...]:
        """Training fields per family in every step."""
        return split_count(self.spec.train.fields_per_step, len(self.spec.train.families))

    def training_fields(self) -> Scenario:
        """All training fields, leading axes (steps, fields_per_step)."""
        t = self.spec.train
        counts = self.step_counts()
        per_family = [self.fields(t.seed, [t.steps * c], [f]) for f, c in zip(t.families, counts)]
        size = max(b.obstacles.radius.shape[-1] for b in per_family)
        shaped = [jax.tree_util.tree_map(lambda x, c=c: x.reshape((t.steps, c) + x.shape[1:]),
                                         pad_obstacles(b, size)) for b, c in zip(per_family, counts)]
        return jax.tree_util.tree_map(lambda *x: jnp.concatenate(x, axis=1), *shaped)

    def validation_fields(self) -> Scenario:
        v = self.spec.validation
        return self.fields(v.seed, split_count(v.fields, len(v.families)))

    def report(self, scenarios: Scenario, settings: Sequence[Gains]) -> dict[str, np.ndarray]:
        """:func:`episode_report` of every (setting, field): numpy arrays of shape (G, F).

        The G·F episodes (``e = g·F + f``) run in batches of :func:`~jaxapf.engine.default_width`
        paired episodes, or of the smallest power of two >= G·F if that is less (a validation set
        is not padded to a whole wide batch), the last batch padded with episode 0; calls of a
        similar size and obstacle count reuse one compiled batch.
        """
        spec = self.spec
        gains = stack_gains(settings)
        n_gains, n_fields = len(settings), scenarios.start.shape[0]
        total = n_gains * n_fields
        width = default_width(total)
        index = episode_index(total, width)
        parts = []
        for e in index.reshape(-1, width):
            parts.append(jax.device_get(_report_batch(_take(scenarios, e % n_fields), _take(gains, e // n_fields),
                                                      spec.sim, spec.mpc, spec.objective, METRICS.names())))
        return {k: np.concatenate([p[k] for p in parts])[:total].reshape(n_gains, n_fields) for k in parts[0]}

    # --- training --------------------------------------------------------------------------

    def initial_state(self) -> TrainState:
        theta = self.spec.reparam.theta(self.spec.init)
        return TrainState(theta=theta, opt_state=self.spec.optimizer().init(theta), best_theta=theta)

    def _validate(self, state: TrainState, val_fields: Scenario, row: dict[str, float]) -> None:
        """Score ``state.theta`` on the validation set into ``row``; update early stopping."""
        r = self.report(val_fields, [self.spec.reparam.gains(state.theta)])
        row |= {"val_loss": float(np.mean(r["loss"])), "val_success": float(np.mean(r["success"])),
                "val_collision": float(np.mean(r["collision"]))}
        row |= {f"val_{t}": float(np.mean(r[t])) for t in TERMS}
        if row["val_loss"] < state.best_val_loss:
            state.best_val_loss, state.best_step, state.bad_validations = row["val_loss"], state.step, 0
            state.best_theta = state.theta
        else:
            state.bad_validations += 1
            state.stopped = state.bad_validations >= self.spec.train.patience

    def next_fields(self, state: TrainState) -> dict[str, int]:
        return {f: state.step * c for f, c in zip(self.spec.train.families, self.step_counts())}

    def train(self, out: pathlib.Path, *, quiet: bool = False) -> TrainState:
        """Run (or resume) training with the checkpoint at ``out/checkpoint.npz``; returns the final
        state. Raises :class:`TuneError` on a non-finite training loss (non-finite per-episode
        gradients are dropped, see :func:`batch_gradient`)."""
        spec, digest = self.spec, self.spec.digest()
        path = out / CHECKPOINT
        state = self.initial_state()
        if path.exists():
            state = TrainState.load(path, digest, state)
        val_fields = self.validation_fields()
        nan_row = dict.fromkeys(HISTORY_COLUMNS, math.nan)
        if not state.history:  # validate the start gains first
            start = time.perf_counter()
            row = nan_row | {"step": 0}
            self._validate(state, val_fields, row)
            state.history.append(row)
            state.train_seconds += time.perf_counter() - start
            state.save(path, digest, self.next_fields(state))
        if state.step >= spec.train.steps or state.stopped:
            return state
        train_fields = self.training_fields()
        bar = Progress(spec.train.steps, f"tune {spec.name}", "step", quiet=quiet, initial=state.step)
        last_val = next(r for r in reversed(state.history) if math.isfinite(r["val_loss"]))
        start = time.perf_counter()
        while state.step < spec.train.steps and not state.stopped:
            batch = jax.tree_util.tree_map(lambda x: x[state.step], train_fields)
            lr = float(self.schedule(state.step))
            theta, opt_state, logs = _train_step(state.theta, state.opt_state, batch, state.step, spec)
            logs = {k: float(v) for k, v in jax.device_get(logs).items()}
            if not math.isfinite(logs["loss"]):
                bar.close()
                raise TuneError(f"non-finite training loss at step {state.step + 1} (gains "
                                f"{spec.reparam.gains(state.theta).floats()}); lower train.learning_rate")
            state.theta, state.opt_state, state.step = theta, opt_state, state.step + 1
            row = nan_row | logs | {"step": state.step, "learning_rate": lr}
            validate = state.step % spec.train.validate_every == 0 or state.step == spec.train.steps
            if validate:
                self._validate(state, val_fields, row)
                last_val = row
            state.history.append(row)
            bar.update(1)
            bar.set_postfix(loss=f"{logs['loss']:.3f}", val_success=f"{last_val['val_success']:.2f}")
            if validate:
                now = time.perf_counter()
                state.train_seconds += now - start
                start = now
                state.save(path, digest, self.next_fields(state))
        bar.close()
        return state

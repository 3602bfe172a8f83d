r"""Gradient estimators of one episode's loss for ``jaxapf tune`` (``train.estimator``).

Closed-loop episodes are stiff and, where the UAV grazes an obstacle or stalls at an unstable
equilibrium, practically discontinuous in the gains: the exact (pathwise) gradient of ``J(θ)`` is
then huge or meaningless, though the loss the tuner should descend, averaged over nearby gains, is
smooth. Following Suh et al. ("Do differentiable simulators give better policy gradients?", ICML
2022), with ``K = 2P`` antithetic perturbations ``θ ± σ ε_p``, ``ε_p ~ N(0, I)`` (``train.samples`` =
P, ``train.sigma`` = σ, in the reparametrised coordinates θ):

- ``pathwise``: ``∇J(θ)``, exact reverse mode (one rollout; the default, as before);
- ``smoothed``: the first-order estimate of the smoothed loss ``J_σ(θ) = E J(θ + σε)``,
  ``ĝ_1 = (1/K) Σ_k ∇J(θ + σ ε_k)`` (randomised smoothing of the gains);
- ``zeroth``: the zeroth-order estimate ``ĝ_0 = (1/P) Σ_p (J(θ+σε_p) - J(θ-σε_p)) ε_p / (2σ)``,
  forward rollouts only, unbiased for ``∇J_σ`` even where ``J`` jumps;
- ``blend``: Suh et al.'s α-order estimate ``α ĝ_1 + (1-α) ĝ_0`` with ``α = v_0/(v_0 + v_1)`` from the
  variances of the two means over the ``P`` independent pairs (``v_1`` from the pairs' mean pathwise
  gradients, ``v_0`` from their zeroth-order samples, ddof 1; ``P >= 2``): the variance-minimising
  mix; and ``α = 0`` where ``ĝ_1`` lies outside ``ĝ_0``'s 95 % ball (``|ĝ_1 - ĝ_0|² > v_0 χ²_{n,0.95}/n``
  for ``n`` coordinates of θ: a pathwise gradient biased by a jump) or is not finite.

The perturbations come from ``(train.seed, step, episode)``, so a run is reproducible and a resumed
one exact. Each estimate costs ``K`` rollouts an episode (``pathwise``: 1), which the tuning budget
counts (:func:`rollouts`).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
from jax import Array

from ..datatypes import Scenario
from .objective import flatten_theta, unflatten_theta

__all__ = ["ESTIMATORS", "rollouts", "episode_gradient"]

#: The values of ``train.estimator``.
ESTIMATORS: tuple[str, ...] = ("pathwise", "smoothed", "zeroth", "blend")

Loss = Callable[[dict[str, Array], Scenario], tuple[Array, dict[str, Array]]]


def rollouts(spec: Any) -> int:
    """Rollouts one training episode of the :class:`~jaxapf.tune.spec.TuneSpec` ``spec`` costs: 1 for
    ``pathwise``, else ``2 · train.samples``."""
    return 1 if spec.train.estimator == "pathwise" else 2 * spec.train.samples


def _chi2_95(n: int) -> float:
    """The 95 % quantile of χ² with ``n`` degrees of freedom: ``|ĝ_1 - ĝ_0|²`` against ``ĝ_0``'s
    variance ``v_0`` spread over ``n`` gains (``v_0 χ²_n / n``, the 95 % ball of an isotropic ``ĝ_0``)."""
    from scipy.stats import chi2

    return float(chi2.ppf(0.95, n))


def episode_gradient(loss: Loss, theta: dict[str, Array], scenario: Scenario, key: Array, spec: Any
                     ) -> tuple[Array, dict[str, Array], dict[str, Array]]:
    """``(loss, terms, gradient)`` of one episode by ``spec.train.estimator`` (a
    :class:`~jaxapf.tune.spec.TuneSpec`; module docstring); for the
    perturbed estimators the loss and terms are the means over the ``K`` perturbed rollouts."""
    t = spec.train
    if t.estimator == "pathwise":
        (value, terms), grad = jax.value_and_grad(loss, has_aux=True)(theta, scenario)
        return value, terms, grad
    names = tuple(theta)
    flat = flatten_theta(theta, names)  # the n coordinates of θ (one per gain, a network's many)
    shapes = {n: jnp.shape(theta[n]) for n in names}
    eps = jax.random.normal(key, (t.samples, flat.shape[0]), flat.dtype)
    signed = jnp.concatenate([eps, -eps])  # (K, n): +ε_p then -ε_p
    perturbed = unflatten_theta(flat + t.sigma * signed, shapes, names)
    if t.estimator == "zeroth":
        values, terms = jax.vmap(loss, in_axes=(0, None))(perturbed, scenario)
        grads = None
    else:
        (values, terms), grads = jax.vmap(jax.value_and_grad(loss, has_aux=True), in_axes=(0, None))(perturbed,
                                                                                                    scenario)
        grads = flatten_theta(grads, names, lead=1)  # (K, n)
    plus, minus = jnp.split(values, 2)
    zo_samples = ((plus - minus) / (2.0 * t.sigma))[:, None] * eps  # (P, n)
    zeroth = jnp.mean(zo_samples, axis=0)
    if t.estimator == "zeroth":
        estimate = zeroth
    else:
        finite = jnp.all(jnp.isfinite(grads))
        grads = jnp.where(finite, grads, 0.0)  # a non-finite sample voids the first-order estimate (below)
        first = jnp.mean(grads, axis=0)
        if t.estimator == "smoothed":
            estimate = jnp.where(finite, first, jnp.nan)
        else:  # the variances of the two means, from the P independent pairs (ddof 1)
            p = zo_samples.shape[0]
            pairs = 0.5 * sum(jnp.split(grads, 2))  # (P, n): (∇J(θ+σε) + ∇J(θ-σε))/2
            v1 = jnp.sum(jnp.var(pairs, axis=0, ddof=1)) / p
            v0 = jnp.sum(jnp.var(zo_samples, axis=0, ddof=1)) / p
            near = jnp.sum((first - zeroth) ** 2) <= v0 * _chi2_95(flat.shape[0]) / flat.shape[0]
            alpha = jnp.where(finite & near, v0 / jnp.maximum(v0 + v1, jnp.finfo(v0.dtype).tiny), 0.0)
            estimate = alpha * first + (1.0 - alpha) * zeroth
    grad = unflatten_theta(estimate, shapes, names)
    return jnp.mean(values), {k: jnp.mean(v) for k, v in terms.items()}, grad

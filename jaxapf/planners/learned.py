r"""A learned repulsive weight ω_θ (docs/spec.md §3, "A learned weight"), planner ``learned_weight``.

The paper's weight (eq. 19) is a hand-made function of two things an obstacle shows the UAV: the
direction cosine ``cos θ`` and the closing speed ``c``. :class:`LearnedWeight` replaces it by a small
network of the same quantities and the clearance relative to the influence distance,

.. math::  \omega_\theta = \mathrm{softplus}\big(f_\theta(\cos\theta,\ \tanh c,\ \min(d/d_s, 1))\big) > 0,

``f_θ`` a two-layer tanh network (:data:`WIDTH` units each). Its parameters θ are one array-valued gain,
``omega_params`` (:data:`OMEGA_PARAMS`, :data:`SIZE` numbers), so a batch of networks is one ``vmap``,
``jaxapf tune`` trains it through the closed loop and ``--gains`` files carry it. The default θ is a fixed
random first layers with a zero last layer and ``softplus(b) = 1``: ω_θ ≡ 1, the classical potential
(``basic``), from which training starts. An input left out (``inputs``, for ablations) is fed as 0.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..gains import GainSpec
from ..validation import ConfigError
from .apf import APF, D_S
from .base import register_planner
from .sight import Sight, dot, norm
from .weights import Weight

__all__ = ["FEATURES", "WIDTH", "SIZE", "OMEGA_PARAMS", "LearnedWeight", "unpack", "network", "initial_params"]

#: What ω_θ reads of an obstacle, in input order.
FEATURES: tuple[str, ...] = ("direction", "closing", "clearance")
#: Units in each hidden layer.
WIDTH = 32
#: Parameters: two tanh layers and a linear output, ``3·W + W + W·W + W + W + 1``.
SIZE = len(FEATURES) * WIDTH + WIDTH + WIDTH * WIDTH + WIDTH + WIDTH + 1


def _shapes() -> tuple[tuple[str, tuple[int, ...]], ...]:
    n, w = len(FEATURES), WIDTH
    return (("w1", (w, n)), ("b1", (w,)), ("w2", (w, w)), ("b2", (w,)), ("w3", (w,)), ("b3", ()))


def unpack(theta: Array) -> dict[str, Array]:
    """The layers of a flat θ (:data:`SIZE`,): ``w1`` (W, 3), ``b1``, ``w2`` (W, W), ``b2``, ``w3`` (W,), ``b3``."""
    out, start = {}, 0
    for name, shape in _shapes():
        size = math.prod(shape)
        out[name] = theta[start:start + size].reshape(shape)
        start += size
    return out


def initial_params(seed: int = 0) -> tuple[float, ...]:
    """The default θ: Glorot-uniform hidden layers from ``seed`` (numpy's PCG64, the same on every
    platform), zero biases, a zero output layer and ``b3 = softplus⁻¹(1)``, so ω_θ ≡ 1."""
    rng = np.random.default_rng(seed)
    parts = []
    for name, shape in _shapes():
        if name in ("w1", "w2"):
            limit = math.sqrt(6.0 / (shape[0] + shape[1]))
            parts.append(rng.uniform(-limit, limit, shape).ravel())
        elif name == "b3":
            parts.append(np.array([math.log(math.e - 1.0)]))
        else:
            parts.append(np.zeros(math.prod(shape)))
    return tuple(float(x) for x in np.concatenate(parts))


OMEGA_PARAMS = GainSpec("omega_params", initial_params(), symbol="θ_ω", shape=(SIZE,),
                        doc=f"parameters θ of the learned weight ω_θ ({len(FEATURES)}-{WIDTH}-{WIDTH}-1 tanh network)")


def network(theta: Array, x: Array) -> Array:
    """``f_θ(x)`` of inputs ``x`` (3, ...) (any trailing obstacle axes): the network before the softplus."""
    layer = unpack(theta)
    tail = (1,) * (x.ndim - 1)
    h = jnp.tanh(jnp.tensordot(layer["w1"], x, axes=1) + layer["b1"].reshape((WIDTH,) + tail))
    h = jnp.tanh(jnp.tensordot(layer["w2"], h, axes=1) + layer["b2"].reshape((WIDTH,) + tail))
    return jnp.tensordot(layer["w3"], h, axes=1) + layer["b3"]


@dataclasses.dataclass(frozen=True)
class LearnedWeight(Weight):
    """ω_θ = softplus(f_θ(cos θ, tanh c, min(d/d_s, 1))): a network of what the paper's ω reads, and the
    clearance (module docstring).

    Attributes:
      inputs: the features fed (a subset of :data:`FEATURES`; the others are fed as 0, for ablations).
    """

    gains: ClassVar[tuple[GainSpec, ...]] = (OMEGA_PARAMS, D_S)
    inputs: tuple[str, ...] = FEATURES

    def __post_init__(self) -> None:
        unknown = [f for f in self.inputs if f not in FEATURES]
        if unknown or not self.inputs:
            raise ConfigError(f"LearnedWeight.inputs = {self.inputs!r}: choose one or more of {', '.join(FEATURES)}")

    def __call__(self, sight: Sight, gains: Any, *, convention: str, eps_v: float) -> Array:
        dist = norm(sight.s)
        speed = jnp.sqrt(dot(sight.v, sight.v) + eps_v**2)
        closing = tuple(a - b for a, b in zip(sight.v, sight.v_o))
        clearance = dist if sight.clearance is None else sight.clearance
        values = {"direction": dot(sight.v, sight.s) / (dist * speed),       # cos θ, 1 heading at it
                  "closing": jnp.tanh(dot(closing, sight.s) / dist),         # tanh c (paper eq. 19)
                  "clearance": jnp.clip(clearance / gains.d_s, 0.0, 1.0)}    # where in the influence zone
        x = jnp.stack(jnp.broadcast_arrays(*(values[f] if f in self.inputs else jnp.zeros_like(values[f])
                                             for f in FEATURES)))
        return jax.nn.softplus(network(gains.omega_params, x))


register_planner("learned_weight", APF(LearnedWeight(), color="tab:green", linestyle="-.",
                                       description="the paper's potential with a learned weight ω_θ > 0 of "
                                                   "cos θ, tanh c and d/d_s (a 3-32-32-1 network)"))

"""``jaxapf tune``: learn the gains through the closed loop with optax, then test them on held-out
fields against the defaults and the black-box tuners (grid, random, CMA-ES, TPE) given the same
episode budget.

==================  ===================================================================
:mod:`.spec`        the tune spec (TOML), validated into a :class:`TuneSpec`
:mod:`.objective`   the smooth surrogate loss and the reparametrisation of the gains
:mod:`.train`       training, validation, early stopping and checkpoints
:mod:`.searches`    the black-box tuners beside it: grid, random, CMA-ES, TPE
:mod:`.proof`       the searches under the same budget and the held-out test
:mod:`.run`         the whole command (:func:`run_tune`)
==================  ===================================================================
"""

from .objective import TERMS, Objective, Reparam, surrogate_loss, surrogate_terms
from .run import run_tune, run_tune_spec, write_gains_toml
from .spec import SearchSpec, TuneSpec, load_tune_spec, parse_tune_spec, read_gains
from .train import TrainState, TuneError, Tuner

__all__ = ["run_tune", "run_tune_spec", "write_gains_toml", "TuneSpec", "SearchSpec", "load_tune_spec",
           "parse_tune_spec", "read_gains", "Objective", "Reparam", "TERMS", "surrogate_terms", "surrogate_loss",
           "Tuner", "TrainState", "TuneError"]

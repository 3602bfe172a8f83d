"""A spec's scenario tables: ``[scenario.params.LABEL]`` applied to a family's defaults, variants (a family
under a name of its own) and ``scale`` (a family shrunk to another vehicle)."""

from __future__ import annotations

import re
from typing import Any

from ..scenarios import FAMILIES, FamilyParams, family_params
from ..scenarios.swarms import SWARM_FAMILIES, swarm_params
from ..validation import ConfigError, check_choice, check_table, relocated
from .schema import OMIT, Key, Table, number

__all__ = ["variant_names", "spec_family_params"]

#: A variant's name: letters, digits and ``_`` (``/`` separates a family from its kind in reports).
_VARIANT = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
#: The longest variant name: a part's file name holds it with 53 more characters at most (its temporary
#: name while it is written, jaxapf.io.lock.staged), within the 255 bytes a file name may have.
MAX_VARIANT_NAME = 128


def variant_names(params: Any) -> tuple[str, ...]:
    """The variants a ``[scenario.params]`` table defines: sub-tables that name their ``family``."""
    if not isinstance(params, dict):
        return ()
    return tuple(label for label, table in params.items()
                 if isinstance(table, dict) and "family" in table and label not in FAMILIES
                 and label not in SWARM_FAMILIES)


def spec_family_params(label: str, overrides: Any, *, swarms: bool = False) -> FamilyParams:
    """A spec's ``[scenario.params.LABEL]`` table applied to a family's defaults (shared by sweep and
    tune specs); a bad value is reported at ``scenario.params.LABEL.KEY``.

    ``LABEL`` is a registered family, or a *variant*: a name of its own whose table names the family
    it varies, ``family = "crossing"``; a variant's rows carry its name in the ``family`` column.
    With ``swarms`` (sweep specs), a swarm family (:data:`~jaxapf.scenarios.swarms.SWARM_FAMILIES`) too,
    giving its :class:`~jaxapf.scenarios.swarms.SwarmParams`. ``scale = {length = L, speed = V}`` shrinks
    the result to another vehicle (:meth:`~jaxapf.scenarios.FamilyParams.scaled`: the table's other values
    are given in the unscaled family's units).
    """
    where = f"scenario.params.{label}"
    overrides = dict(check_table(where, overrides))
    base = overrides.pop("family", label)
    scale = _SCALE(f"{where}.scale", overrides.pop("scale", {}))
    registered = FAMILIES.names() + (SWARM_FAMILIES.names() if swarms else ())
    if label in registered and base != label:
        raise ConfigError(f"{where}.family = {base!r}: {label} is a registered family; give the variant a name "
                          "of its own")
    if label not in registered:
        if not _VARIANT.fullmatch(label):
            raise ConfigError(f"{where}: a variant's name is letters, digits and '_', starting with a letter")
        if len(label) > MAX_VARIANT_NAME:
            raise ConfigError(f"{where[:60]}…: a variant's name is at most {MAX_VARIANT_NAME} characters (it is "
                              f"{len(label)}): it names the parts' files, which a file system holds to 255 bytes")
        check_choice(f"{where}.family", base, registered)
    try:
        params = swarm_params(base, **overrides) if base in SWARM_FAMILIES else family_params(base, **overrides)
        return params.scaled(**scale) if scale else params
    except ConfigError as err:
        raise relocated(err, f"scenario.{base}", where) from None


#: A ``[scenario.params.LABEL]`` table's ``scale``: the factors of :meth:`FamilyParams.scaled`, within a
#: thousandfold either way (past that no vehicle is meant, and float32 fields lose their obstacles).
_SCALE = Table({"length": Key(number(1e-3, 1e3), OMIT), "speed": Key(number(1e-3, 1e3), OMIT)})

"""Named registries: the extension points of jaxapf.

Every component a user can add -- planners, safety filters, plants, scenario families, metrics,
declared gains -- lives in a :class:`Registry` owned by the module of its concept
(:data:`jaxapf.planners.PLANNERS`, :data:`jaxapf.control.FILTERS`, :data:`jaxapf.world.PLANTS`,
:data:`jaxapf.scenarios.FAMILIES`, :data:`jaxapf.metrics.METRICS`, :data:`jaxapf.gains.GAINS`).
Registering is the only step: sweep specs, CLI flags and help texts, reports, ``jaxapf list`` and
``jaxapf tune`` read the registries, so nothing else is edited (``docs/extending.md``).

An entry is looked up by name when a program is traced, and the name is part of the static
configuration, so a new name compiles a new program. Re-registering a name would leave compiled
programs of the old entry in JAX's caches; it is refused unless ``replace=True``.
"""

from __future__ import annotations

from typing import Callable, Generic, Iterator, Sequence, TypeVar

from .text import plain_text
from .validation import ConfigError, did_you_mean

__all__ = ["Registry", "LOOP", "loop_rank"]

T = TypeVar("T")

#: The kinds of component of the closed loop (their registries' ``what``), in the order in which the
#: gains and metrics they declare are listed: a sweep's columns and a tuner's parameter vector follow
#: this order and their declaration order within a kind, never which module happened to be imported first.
LOOP = ("planner", "safety filter", "plant", "sensor", "disturbance", "estimator")


def loop_rank(kind: str | None) -> int:
    """Where the gains or metrics declared by a component of ``kind`` are listed (:data:`LOOP`); those
    of no component kind (declared directly) come after every kind's."""
    return LOOP.index(kind) if kind in LOOP else len(LOOP)


class Registry(Generic[T]):
    """Entries of one kind by name, in registration order.

    Args:
      what: what an entry is, in words (``"planner"``); used in error messages.
      describe: one line about an entry for ``jaxapf list`` (default: its docstring's first line).
      on_register: called as ``hook(entry, registry)`` with every entry before it is entered (a
        component registry passes :func:`jaxapf.gains.declare_entry_gains` and
        :func:`jaxapf.metrics.register_entry_metrics`: registering a component declares its gains and
        metrics).
      listed_as: its target of ``jaxapf list`` (default ``what`` + "s").
      role: what an entry does, in a few words, for help texts (default ``what``).
      rank: ``rank(name)`` orders the entries (ties in registration order); default registration order.
    """

    def __init__(self, what: str, describe: Callable[[T], str] | None = None,
                 on_register: Sequence[Callable[[T, "Registry[T]"], object]] = (), *,
                 listed_as: str | None = None, role: str | None = None,
                 rank: Callable[[str], int] | None = None) -> None:
        self.what = what
        self.listed_as = listed_as or f"{what}s"
        self.role = role or what
        self._entries: dict[str, T] = {}
        self._describe = describe
        self._on_register = tuple(on_register)
        self._rank = rank
        self._order: tuple[str, ...] | None = None

    def register(self, name: str, entry: T, *, replace: bool = False) -> T:
        """Add ``entry`` under ``name`` (letters, digits and ``_``, starting with a letter); returns it."""
        if not isinstance(name, str) or not name or not name[0].isalpha() or not name.replace("_", "").isalnum():
            raise ConfigError(f"{self.what} name {name!r} must be letters, digits and '_', starting with a letter")
        if name in self._entries and not replace and self._entries[name] != entry:
            raise ConfigError(f"a {self.what} named {name!r} is registered already; pass replace=True to replace it")
        for hook in self._on_register:
            hook(entry, self)
        self._entries[name] = entry
        self._order = None
        return entry

    def get(self, name: str, where: str | None = None) -> T:
        """The entry ``name``; :class:`ConfigError` naming ``where`` (default: the registry) otherwise."""
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            at = where or self.what
            raise ConfigError(f"{at} = {name!r} is not a registered {self.what}{did_you_mean(name, self.names())}; "
                              f"choose one of {', '.join(self.names()) or '(none registered)'}") from None

    __getitem__ = get

    def names(self) -> tuple[str, ...]:
        if self._order is None:
            self._order = tuple(sorted(self._entries, key=self._rank) if self._rank else self._entries)
        return self._order

    def items(self) -> tuple[tuple[str, T], ...]:
        return tuple((name, self._entries[name]) for name in self.names())

    def describe(self, name: str) -> str:
        """One line about entry ``name``, plain text (reST markup removed): the ``describe`` given to
        the registry, else the entry's ``summary`` (one class registered in several configurations),
        else the first paragraph of the entry's docstring."""
        entry = self.get(name)
        if self._describe is not None:
            return plain_text(self._describe(entry))
        if isinstance(getattr(entry, "summary", None), str):
            return plain_text(entry.summary)
        doc = (type(entry).__doc__ if not isinstance(entry, type) else entry.__doc__) or ""
        return plain_text(doc.strip().split("\n\n")[0])

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.what!r}: {', '.join(self.names())})"

"""The jaxapf command line (:mod:`.commands`), the program around it (:mod:`.program`: signals and exit)
and the registries' catalogue it is built from without importing JAX (:mod:`.catalog`). Imported
lazily: the program's entry point, :mod:`.program`, runs its first lines before the command line is
imported."""

from importlib import import_module

__all__ = ["main", "console", "build_parser"]
_LAZY = {"main": ".commands", "build_parser": ".commands", "console": ".program"}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(_LAZY[name], __name__), name)

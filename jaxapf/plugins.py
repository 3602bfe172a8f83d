"""Plugins: modules that register components from outside the package.

A plugin is a Python module that registers planners, weights, filters, plants, families or metrics
when imported (``docs/extending.md``). Sweep and tune specs name theirs (``plugins = [...]``, so
a spec is self-contained and its output records what it needs); the CLI's ``--plugin`` imports one
for any command. A plugin is a module name (``mypackage.planners``) or a path to a ``.py`` file.
"""

from __future__ import annotations

import importlib
import importlib.util
import pathlib
import sys
from types import ModuleType
from typing import Any, Sequence

from .validation import ConfigError, first_line

__all__ = ["load_plugin", "load_plugins", "check_plugins"]


def load_plugin(name: str, where: str = "plugin") -> ModuleType:
    """Import the plugin ``name`` (a module name or a ``.py`` path); a module imports once."""
    try:
        if name.endswith(".py"):
            path = pathlib.Path(name).resolve()
            if not path.is_file():
                raise ConfigError(f"{where} = {name!r}: no such file")
            module_name = f"jaxapf_plugin_{path.stem}_{abs(hash(str(path))):x}"
            if module_name in sys.modules:
                return sys.modules[module_name]
            spec = importlib.util.spec_from_file_location(module_name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[module_name] = module
            try:
                spec.loader.exec_module(module)
            except BaseException:
                del sys.modules[module_name]
                raise
            return module
        return importlib.import_module(name)
    except ConfigError:
        raise
    except ImportError as err:
        raise ConfigError(f"{where} = {name!r} cannot be imported: {first_line(err)}") from None
    except Exception as err:  # noqa: BLE001 - a plugin's own error, reported in one line
        raise ConfigError(f"{where} = {name!r} failed while importing: "
                          f"{type(err).__name__}: {first_line(err)}") from None


def check_plugins(where: str, value: Any) -> tuple[str, ...]:
    """A list of plugin names (strings), as a spec gives it."""
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise ConfigError(f"{where} = {value!r} must be a list of module names or .py paths")
    return tuple(value)


def load_plugins(names: Sequence[str], where: str = "plugins") -> None:
    """Import every plugin of ``names``."""
    for i, name in enumerate(names):
        load_plugin(name, f"{where}[{i}]")

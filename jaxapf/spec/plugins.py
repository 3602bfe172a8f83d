"""Plugins: modules that register components from outside the package.

A plugin is a Python module that registers planners, weights, filters, plants, families or metrics
when imported (``docs/extending.md``). Sweep and tune specs name theirs (``plugins = [...]``, so
a spec is self-contained and its output records what it needs); the CLI's ``--plugin`` imports one
for any command. A plugin is a module name (``mypackage.planners``) or a path to a ``.py`` file;
a spec's relative paths are read from the spec file's folder (``base``), ``--plugin``'s from the
current directory.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pathlib
import re
import sys
from types import ModuleType
from typing import Any, Sequence

from ..validation import ConfigError, first_line

__all__ = ["load_plugin", "load_plugins", "check_plugins", "plugin_path", "plugin_digests", "plugin_failure",
           "LOADED"]

#: Every plugin this process has imported, in order, as ``(name, path)`` (``path``: the ``.py``
#: file, None for a module name): a second process imports the same ones to see the same registries
#: (the report's, :class:`jaxapf.report.worker.RowWorker`).
LOADED: list[tuple[str, str | None]] = []


def plugin_path(name: str, base: str | os.PathLike | None = None) -> str:
    """What plugin ``name`` imports: a ``.py`` path made absolute (a relative one from ``base``,
    default the current directory), a module name as it is."""
    if not name.endswith(".py"):
        return name
    path = pathlib.Path(name).expanduser()
    return str((path if path.is_absolute() else pathlib.Path(base or ".") / path).resolve())


def load_plugin(name: str, where: str = "plugin", path: str | os.PathLike | None = None) -> ModuleType:
    """Import the plugin ``name`` (a module name or a ``.py`` path); a module imports once.
    ``path``: the file to import for a ``.py`` plugin (default :func:`plugin_path` of ``name``)."""
    try:
        if name.endswith(".py"):
            path = pathlib.Path(path if path is not None else plugin_path(name))
            if not path.is_file():
                shown = "" if str(path) == name else f" ({path})"
                raise ConfigError(f"{where} = {name!r}: no such file{shown}")
            module_name = f"jaxapf_plugin_{path.stem}_{abs(hash(str(path))):x}"
            if module_name in sys.modules:
                return sys.modules[module_name]
            loaded = (name, str(path))
            spec = importlib.util.spec_from_file_location(module_name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[module_name] = module
            try:
                spec.loader.exec_module(module)
            except BaseException:
                del sys.modules[module_name]
                raise
        else:
            module, loaded = importlib.import_module(name), (name, None)
        if loaded not in LOADED:
            LOADED.append(loaded)
        return module
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


def load_plugins(names: Sequence[str], where: str = "plugins", base: str | os.PathLike | None = None,
                 paths: Sequence[str] | None = None) -> tuple[str, ...]:
    """Import every plugin of ``names`` (relative ``.py`` paths from ``base``, default the current
    directory, or from ``paths``, one per name); returns what each imported (:func:`plugin_path`)."""
    paths = tuple(paths) if paths is not None else tuple(plugin_path(name, base) for name in names)
    for i, (name, path) in enumerate(zip(names, paths)):
        load_plugin(name, f"{where}[{i}]", path)
    return paths


def _sources() -> list[tuple[str, str | None]]:
    """Each plugin this process imported (:data:`LOADED`) with the file its code is in (a module's own; None where
    it has none)."""
    return [(name, path if path is not None else getattr(sys.modules.get(name), "__file__", None))
            for name, path in LOADED]


def _key(name: str, source: str | None) -> str:
    """How a plugin is known across runs: a ``.py`` file by its real path, a module by its name."""
    return os.path.realpath(source) if name.endswith(".py") and source else name


def plugin_digests() -> dict[str, str]:
    """The sha256 of every plugin this process imported (``-`` for a module without a file of its own), keyed by
    its real path (a module: its name), so that what was flown with an edited plugin is told apart."""
    import hashlib

    from ..io.names import read_own

    found = {}
    for name, source in _sources():
        try:
            digest = hashlib.sha256(read_own(source, 1 << 26)).hexdigest() if source else "-"
        except (OSError, ConfigError):  # gone, or no longer a regular file of sane size: no digest to compare
            digest = "-"
        found[_key(name, source)] = digest
    return found


#: A frame of a traceback another process formatted (``concurrent.futures``' remote traceback).
_REMOTE_FRAME = re.compile(r'File "(?P<file>[^"]+)", line (?P<line>\d+), in (?P<func>\S+)')


def _ray_cause(err: BaseException) -> BaseException | None:
    """The exception a Ray worker raised where ``err`` is its task's error (whose text is the worker's traceback)."""
    cause = getattr(err, "cause", None)
    ray_task = any(c.__name__ == "RayTaskError" for c in type(err).__mro__)
    return cause if ray_task and isinstance(cause, BaseException) else None


def _remote_text(err: BaseException) -> str | None:
    """The traceback another process formatted for ``err``: ``concurrent.futures``' remote traceback, or a Ray
    task's error (its worker's traceback); None for an error raised here."""
    return str(err) if type(err).__name__ == "_RemoteTraceback" or _ray_cause(err) is not None else None


def _frames(err: BaseException) -> list[tuple[str, int, str]]:
    """``(file, line, function)`` of each frame ``err`` was raised through, outermost first; a remote traceback's
    from its text."""
    import traceback

    text = _remote_text(err)
    if text is not None:
        return [(m["file"], int(m["line"]), m["func"]) for m in _REMOTE_FRAME.finditer(text)]
    return [(f.f_code.co_filename, line, f.f_code.co_name) for f, line in traceback.walk_tb(err.__traceback__)]


def plugin_failure(err: BaseException) -> str | None:
    """``the plugin P failed at FILE:LINE in FUNC: TYPE: message`` where ``err`` (or the error it was raised from,
    in this process or in a worker's, a Ray task's included) failed in a plugin's own code: the deepest of its
    frames in jaxapf or a plugin this process imported is the plugin's. Else None: a failure of jaxapf's own (a
    plugin calling it included), whose traceback is kept for a bug report."""
    package = os.path.dirname(os.path.dirname(os.path.realpath(__file__))) + os.sep
    files, folders = {}, {}
    for name, source in _sources():
        if not source:
            continue
        shown = pathlib.Path(source).name if name.endswith(".py") else name
        files[os.path.realpath(source)] = shown
        if pathlib.Path(source).name == "__init__.py":  # a package: every file under it
            folders[os.path.dirname(os.path.realpath(source)) + os.sep] = shown
    shown_err, cause, seen = err, err, set()
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        shown_err = _ray_cause(cause) or shown_err  # a Ray task's error: the exception the worker raised
        deepest = None
        for file, line, func in _frames(cause):
            where = os.path.realpath(file)
            owner = files.get(where) or next((n for d, n in folders.items() if where.startswith(d)), None)
            if owner is not None:
                deepest = (owner, pathlib.Path(where).name, line, func)
            elif where.startswith(package):
                deepest = None  # jaxapf's own code, deeper than any plugin frame so far
        if deepest is not None:
            name, file, line, func = deepest
            return (f"the plugin {name} failed at {file}:{line} in {func}: {type(shown_err).__name__}: "
                    f"{first_line(shown_err)}")
        if type(cause.__cause__).__name__ != "_RemoteTraceback":
            shown_err = cause.__cause__
        cause = cause.__cause__
    return None

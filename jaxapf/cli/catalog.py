"""What the command line shows before anything runs, without importing JAX.

``jaxapf --help``, ``jaxapf CMD --help``, ``jaxapf list ...`` and argument errors need the
registries' names, descriptions and declared gains, but the registries live in the modules that
define the components, which import JAX (a few seconds on a small machine). The first command
reads them live and writes this *catalogue* of what it read, as JSON, under
``$XDG_CACHE_HOME/jaxapf/cli/`` (default ``~/.cache``); later commands read the catalogue instead.

The file's name carries a fingerprint of the package's sources (every ``.py`` file's path, size and
modification time) and of the Python version, so an edited or upgraded jaxapf reads the registries
live again and writes a new catalogue: a catalogue never disagrees with the registries it was read
from. Plugins (``--plugin``) register components at import, so with a plugin the registries are read
live. Nothing here imports JAX; :func:`live` imports the registries.
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib
import sys
import tempfile
from typing import Any

__all__ = ["catalog", "live", "fingerprint", "catalog_path"]

_VERSION = 2  # of the catalogue's layout


def fingerprint() -> str:
    """sha256 of every package source file's path, size and mtime, the Python version and the layout."""
    root = pathlib.Path(__file__).resolve().parents[1]  # the package's sources
    h = hashlib.sha256(f"{_VERSION}\0{sys.version}\0{root}".encode())
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        for name in sorted(filenames):
            if name.endswith(".py"):
                st = os.stat(os.path.join(dirpath, name))
                h.update(f"{os.path.relpath(os.path.join(dirpath, name), root)}\0{st.st_size}\0{st.st_mtime_ns}\n"
                         .encode())
    return h.hexdigest()


def catalog_path() -> pathlib.Path:
    """Where the catalogue of these sources is kept."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "jaxapf" / "cli" / f"catalog-{fingerprint()[:20]}.json"


def live() -> dict[str, Any]:
    """The catalogue read from the registries as they are in this process (imports them, and JAX)."""
    from ..config import CONVENTIONS, MPCConfig, SimConfig
    from ..engine.components import COMPONENTS
    from ..gains import GAINS
    from ..metrics import METRICS
    from ..metrics.swarm import SWARM_METRICS, swarm_metric_names
    from ..scenarios import FAMILIES
    from ..scenarios.swarms import SWARM_FAMILIES

    lists = {}
    for registry in (*COMPONENTS.values(), FAMILIES, SWARM_FAMILIES, METRICS, SWARM_METRICS, GAINS):
        entries = []
        for name in registry.names():
            entry = {"name": name, "describe": registry.describe(name)}
            if registry in COMPONENTS.values():
                entry["gains"] = [g.name for g in registry.get(name).gains]
            entries.append(entry)
        if registry is SWARM_METRICS:  # the components' counts, summed over the UAVs
            entries += [{"name": n, "describe": f"{METRICS.describe(n)}; summed over the UAVs"}
                        for n in swarm_metric_names() if n not in SWARM_METRICS]
        lists[registry.listed_as] = entries
    defaults = SimConfig().flat()
    return {
        "lists": lists,
        "components": [{"key": key, "list": registry.listed_as, "role": registry.role, "default": defaults[key]}
                       for key, registry in COMPONENTS.items()],
        # the gains a --NAME flag sets: the numbers (an array-valued gain comes in a --gains file)
        "gains": [{"name": n, "doc": s.doc, "unit": s.unit, "default": float(s.default)} for n, s in GAINS.items()
                  if not s.shape],
        "defaults": {k: defaults[k] for k in ("convention", "dt")},
        "conventions": list(CONVENTIONS),
        "mpc": {"horizon": MPCConfig.horizon, "iters": MPCConfig.iters},
    }


#: The lists the command line reads by name (every registry's are there too, named by the components).
_NAMED_LISTS = ("planners", "families", "swarm-families", "metrics", "gains")


def well_formed(data: Any) -> bool:
    """Whether ``data`` has everything the command line reads from a catalogue, of the types it reads
    (a cache edited or cut short is read live again instead of failing every command)."""
    def entries(items: Any, keys: tuple[str, ...]) -> bool:
        return isinstance(items, list) and all(isinstance(e, dict) and all(k in e for k in keys) and
                                               isinstance(e.get("name", e.get("key", "")), str) for e in items)
    try:
        lists = data["lists"]
        return (isinstance(lists, dict) and all(entries(v, ("name", "describe")) for v in lists.values())
                and all(k in lists for k in _NAMED_LISTS)
                and entries(data["components"], ("key", "list", "role", "default"))
                and all(c["list"] in lists for c in data["components"])
                and entries(data["gains"], ("name", "doc", "unit", "default"))
                and isinstance(data["conventions"], list) and all(isinstance(c, str) for c in data["conventions"])
                and data["defaults"]["convention"] in data["conventions"] and isinstance(data["defaults"]["dt"], float)
                and all(isinstance(data["mpc"][k], int) for k in ("horizon", "iters")))
    except (KeyError, TypeError, AttributeError):
        return False


def catalog(*, fresh: bool = False) -> dict[str, Any]:
    """The catalogue: read from the cache when there is one for these sources, else read live and
    cached (an unwritable cache is skipped). ``fresh``: read live, cache nothing (after plugins)."""
    if fresh:
        return live()
    path = catalog_path()
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if well_formed(data):
            return data
    except (OSError, ValueError, RecursionError):
        pass
    data = live()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, prefix=".catalog-", suffix=".tmp", delete=False,
                                         encoding="utf-8") as f:
            json.dump(data, f)
        os.replace(f.name, path)
    except OSError:
        pass
    return data


def names(cat: dict[str, Any], what: str) -> tuple[str, ...]:
    """The registered names of ``jaxapf list`` target ``what``."""
    return tuple(e["name"] for e in cat["lists"][what])

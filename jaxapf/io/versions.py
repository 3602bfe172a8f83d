"""Versions of everything that can change a number, recorded with every result."""

from __future__ import annotations

import hashlib
import os
import pathlib
import platform
import stat
from importlib import metadata

import jax

__all__ = ["versions", "source_digest", "processor"]


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def versions() -> dict[str, str]:
    """jaxapf, jax, jaxlib, numpy, optax versions, Python, platform and the default JAX device."""
    device = jax.devices()[0]
    return {
        "jaxapf": _version("jaxapf"),
        "jax": jax.__version__,
        "jaxlib": _version("jaxlib"),
        "numpy": _version("numpy"),
        "optax": _version("optax"),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_count": str(os.cpu_count()),
        "device": f"{device.platform}:{device.device_kind}",
        "device_count": str(jax.device_count()),
        "x64": str(jax.config.jax_enable_x64),
    }


def source_digest(root: pathlib.Path | None = None) -> str:
    """sha256 of jaxapf's Python source (every ``.py`` file of the package, or of ``root``, by relative path; not
    a dot-file): an edit the version number does not show still changes what flies."""
    root = pathlib.Path(__file__).resolve().parents[1] if root is None else root
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        name = path.relative_to(root)
        if any(part.startswith(".") for part in name.parts):  # an editor's lock or backup
            continue
        try:  # a link is read through; a FIFO opened without waiting, then passed over like a folder
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        except FileNotFoundError:  # a dangling link, or a file removed since the listing
            continue
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            continue
        with open(fd, "rb") as fh:
            h.update(name.as_posix().encode() + b"\0")
            while block := fh.read(1 << 20):  # in blocks: a file linked here may be of any size
                h.update(block)
            h.update(b"\0")
    return h.hexdigest()


def processor() -> str:
    """The host processor's model (Linux's ``/proc/cpuinfo``, else what :mod:`platform` knows): XLA compiles for
    the instructions it has, which may round float32 sums apart."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()

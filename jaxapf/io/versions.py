"""Versions of everything that can change a number, recorded with every result."""

from __future__ import annotations

import os
import platform
from importlib import metadata

import jax

__all__ = ["versions"]


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

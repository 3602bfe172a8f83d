"""The process's JAX runtime: float type, persistent compilation cache and CPU devices, set once before
anything runs on a device (every command, the studies and the benchmarks)."""

from __future__ import annotations

import os
import pathlib

import jax

from ..validation import ConfigError, first_line

__all__ = ["configure_jax", "default_cache_dir"]


def default_cache_dir(what: str = "xla") -> pathlib.Path:
    """``$XDG_CACHE_HOME/jaxapf/WHAT`` (default ``~/.cache/jaxapf/xla``, the compilation cache; ``oracle``: the
    solvability oracle's kept answers, :mod:`jaxapf.scenarios.answers`)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "jaxapf" / what


def configure_jax(*, x64: bool = False, cache_dir: str | os.PathLike | None = None,
                  cpu_devices: int | None = None) -> None:
    """Process-wide JAX settings for a sweep; call before anything runs on a device.

    Args:
      x64: float64 everywhere (``jax_enable_x64``).
      cache_dir: persistent compilation cache (``jax_compilation_cache_dir``); programs that took
        more than 0.1 s to compile are stored there and loaded by later runs. ``None``: no cache.
      cpu_devices: on the CPU platform, split the host into this many JAX devices
        (``jax_num_cpu_devices``), one per core being the useful setting (more are refused); ignored when
        ``XLA_FLAGS`` already forces a count, or when JAX runs on an accelerator.
    """
    if x64:
        jax.config.update("jax_enable_x64", True)
    if cache_dir is not None:
        try:
            pathlib.Path(cache_dir).mkdir(parents=True, exist_ok=True)
        except FileExistsError:  # a file, or a link to nothing
            raise ConfigError(f"the compilation cache {cache_dir} is not a folder; run with --no-cache, or give "
                              "another folder (jaxapf sweep --cache-dir, or XDG_CACHE_HOME)") from None
        except OSError as err:
            raise ConfigError(f"the compilation cache {cache_dir} cannot be made: {err.strerror or first_line(err)}; "
                              "run with --no-cache, or give another folder (jaxapf sweep --cache-dir, or "
                              "XDG_CACHE_HOME)") from None
        jax.config.update("jax_compilation_cache_dir", str(cache_dir))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.1)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    forced = "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "")
    if cpu_devices is not None and not forced and _cpu_platform():
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        if cpu_devices > cores:  # each device is memory and threads, and no faster
            raise ConfigError(f"--devices = {cpu_devices} is more than the {cores} CPU core(s) this process may use; "
                              f"at most {cores} (one device per core is the useful most)")
        try:
            jax.config.update("jax_num_cpu_devices", int(cpu_devices))
        except RuntimeError:  # JAX already ran something in this process: keep its devices
            pass


def _cpu_platform() -> bool:
    """Whether JAX will run on the CPU here: ``JAX_PLATFORMS`` says so, or no accelerator plugin is
    installed (told without starting a backend, which would fix the CPU's device count too early)."""
    import importlib.metadata
    import importlib.util

    platforms = (jax.config.jax_platforms or os.environ.get("JAX_PLATFORMS") or "").strip().lower()
    if platforms:
        return platforms.split(",")[0] == "cpu"
    return not importlib.metadata.entry_points(group="jax_plugins") and importlib.util.find_spec("jax_plugins") is None

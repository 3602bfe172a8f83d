"""The jaxapf command line (:mod:`.commands`) and the registries' catalogue it is built from without
importing JAX (:mod:`.catalog`)."""

from .commands import build_parser, console, main

__all__ = ["main", "console", "build_parser"]

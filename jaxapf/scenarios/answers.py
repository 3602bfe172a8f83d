"""The solvability oracle's answers kept on disk: asked once per field, vehicle and episode length.

An answer is a property of the fields, the vehicle (``r_uav``, ``v_max``), the episode (``t_max``,
``r_goal``) and the oracle's code, so a sweep that flies the same fields again (a rerun into another
output, ``jaxapf compare``'s test sweeps, a study rerun) reads it instead of asking again. Each chunk's
answers are one file, ``<folder>/<key>.npy``, named by the SHA-256 of all of these (the fields' arrays
byte for byte; :func:`key`): a different field, vehicle or oracle is another name. The file is inert
data: a NumPy array read without pickles, through jaxapf's checked opener (a regular file, no link
followed, never blocking, at most the bytes the answers take), and used only if it is a bool array of
the chunk's shape; anything else is asked again and written anew. Writing is atomic, and a folder that
cannot be written only means asking again. The commands keep them in ``$XDG_CACHE_HOME/jaxapf/oracle``
(``jaxapf.engine.runtime.default_cache_dir("oracle")``).
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import pathlib
from typing import Any, Callable

import numpy as np

__all__ = ["key", "recall", "keep", "remembered"]


@functools.cache
def _oracle_version() -> str:
    """The oracle's code (its module's source) and jaxapf's version, hashed: new code asks again."""
    from importlib.metadata import PackageNotFoundError, version

    from . import solvability

    try:
        release = version("jaxapf")
    except PackageNotFoundError:
        release = "unknown"
    return hashlib.sha256(pathlib.Path(solvability.__file__).read_bytes() + release.encode()).hexdigest()


def key(arrays: dict[str, Any], question: dict[str, Any]) -> str:
    """The SHA-256 naming the answers about ``arrays`` (the fields, by name) under ``question`` (the
    vehicle, the episode, the oracle's options: JSON-able)."""
    h = hashlib.sha256(_oracle_version().encode())
    h.update(json.dumps(question, sort_keys=True).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(json.dumps([name, a.dtype.str, a.shape]).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def recall(where: pathlib.Path, name: str, shape: tuple[int, ...]) -> np.ndarray | None:
    """The answers kept as ``name`` in ``where``, if they are a bool array of ``shape``; else None."""
    from ..io.names import read_own

    limit = 1024 + int(np.prod(shape, dtype=np.int64))  # the .npy header and one byte an answer
    try:
        data = read_own(where / f"{name}.npy", limit)
        answers = np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)
    except (OSError, ValueError, EOFError):  # missing, planted or too large (ConfigErrors are ValueErrors), damaged
        return None
    return answers if answers.dtype == np.bool_ and answers.shape == tuple(shape) else None


def keep(where: pathlib.Path, name: str, answers: np.ndarray) -> None:
    """Keep ``answers`` as ``name`` in ``where`` (atomically); a folder that cannot take it is left as it is."""
    from ..io.lock import write_atomic
    from ..io.names import subfolder

    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.ascontiguousarray(answers, np.bool_), allow_pickle=False)
    try:
        where.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(subfolder(where) / f"{name}.npy", buffer.getvalue(), durable=False)
    except (OSError, ValueError):  # read-only, full, or a name planted there: asking again is the cost
        pass


def remembered(where: os.PathLike | None, arrays: dict[str, Any], question: dict[str, Any], shape: tuple[int, ...],
               ask: Callable[[], np.ndarray]) -> np.ndarray:
    """The answers about ``arrays`` under ``question``: kept in ``where``, else ``ask()``-ed and kept there
    (``where`` None: asked, nothing kept)."""
    if where is None:
        return ask()
    where, name = pathlib.Path(where), key(arrays, question)
    answers = recall(where, name, shape)
    if answers is None:
        answers = np.asarray(ask(), np.bool_)
        keep(where, name, answers)
    return answers

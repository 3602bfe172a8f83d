"""Fixtures shared across the test tree."""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import pytest

from jaxapf import Obstacles, Scenario

ROOT = pathlib.Path(__file__).resolve().parents[1]


def pytest_configure(config):
    """One persistent compilation cache for the processes of one run (the xdist workers inherit its folder from
    the process that starts them): a program one test module compiled is loaded, not compiled again, by a later
    module (each frees its programs), by the other worker or by a command a test runs (it is the run's
    ``XDG_CACHE_HOME``, so the user's own cache is never read or written). A folder of its own per run, removed
    at its end, so no run reads another's programs. Every program is stored, however quick to compile: a
    module's small array operations are loaded by the next."""
    import os
    import tempfile

    from jaxapf.engine.runtime import configure_jax, default_cache_dir

    if "JAXAPF_TESTS_XLA" not in os.environ:  # the run's first process: the controller, or the only one
        os.environ["JAXAPF_TESTS_XLA"] = config._jaxapf_xla = tempfile.mkdtemp(prefix="jaxapf-tests-xla-")
        os.environ["XDG_CACHE_HOME"] = os.environ["JAXAPF_TESTS_XLA"]
    configure_jax(cache_dir=default_cache_dir())
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(session, config, items):
    """Before ``-m`` deselects any: how many tests each tier holds (``config.jaxapf_tiers``: ``{"all": n,
    "fast": n}``), where this run collected the whole suite (no paths, ``-k`` or ``--deselect`` narrowed it);
    None otherwise. tests/test_readme_rules.py holds the suite's recorded times to these counts."""
    whole = (all(pathlib.Path(a).resolve() == ROOT / "tests" for a in config.args) and not config.option.keyword
             and not config.getoption("deselect", None))
    config.jaxapf_tiers = {"all": len(items), "fast": sum(1 for i in items if i.get_closest_marker("slow") is None)
                           } if whole else None


def pytest_unconfigure(config):
    import shutil

    if hasattr(config, "_jaxapf_xla"):
        shutil.rmtree(config._jaxapf_xla, ignore_errors=True)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Under ``JAXAPF_SUITE_PROFILE=FOLDER`` (benchmarks/suite.py sets it), one JSON line per test in
    ``FOLDER/<worker>.jsonl``: its wall seconds (setup, call and teardown), the seconds JAX spent tracing,
    lowering and compiling in this process meanwhile, and the CPU seconds of the programs it ran that ended."""
    import os

    folder = os.environ.get("JAXAPF_SUITE_PROFILE")
    if not folder:
        yield
        return
    import json
    import resource
    import time

    spent = _compile_seconds()
    before, children, start = dict(spent), resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    yield
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    row = {"test": item.nodeid, "wall_s": round(wall, 4),
           "subprocess_cpu_s": round(after.ru_utime + after.ru_stime - children.ru_utime - children.ru_stime, 4),
           **{k: round(spent[k] - before.get(k, 0.0), 4) for k in spent}}
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(os.path.join(folder, f"{worker}.jsonl"), "a") as out:
        out.write(json.dumps(row) + "\n")


_SPENT: dict = {}


def _compile_seconds() -> dict:
    """Seconds this process has spent on JAX's trace, lowering and backend compile (a listener installed at the
    first call)."""
    if not _SPENT:
        import jax.monitoring

        events = {"/jax/core/compile/jaxpr_trace_duration": "trace_s",
                  "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
                  "/jax/core/compile/backend_compile_duration": "compile_s"}
        _SPENT.update({v: 0.0 for v in events.values()})

        def listen(event, duration, **_):
            if event in events:
                _SPENT[events[event]] += duration
        jax.monitoring.register_event_duration_secs_listener(listen)
    return _SPENT


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Free a module's compiled programs after it: a worker process runs a hundred modules, and keeping every
    program they compiled made the suite's memory grow with their number (a peak of 11 GB for the whole suite
    when each worker kept up to 2 GB of them). A later module loads what it shares from the run's cache."""
    yield
    jax.clear_caches()


@pytest.fixture
def tiny_spec(tmp_path) -> pathlib.Path:
    """A sweep spec file of two settings × four `trap` fields of 10 steps: a real command in seconds."""
    path = tmp_path / "tiny.toml"
    path.write_text('name = "tiny"\n[scenario]\nfamilies = ["trap"]\nfields = 4\nseed = 2\n'
                    '[sim]\nt_max = 1.0\nhorizon = 3\niters = 3\n[grid]\nk_rep = [5.0, 10.0]\n')
    return path


@pytest.fixture
def full_disk(monkeypatch):
    """``full_disk(prefix)``: from now on, opening a temporary file whose name starts with ``prefix`` (or
    every one after the first ``after``) fails as a full disk does (ENOSPC)."""
    import errno
    import os

    import jaxapf.io.lock as lock

    real, opened = lock.open_own, []

    def arm(prefix: str = "", after: int = 0) -> None:
        def full(path, flags, mode=0o644):
            opened.append(path)
            if pathlib.Path(path).name.startswith(prefix) and len(opened) > after:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
            return real(path, flags, mode)
        monkeypatch.setattr(lock, "open_own", full)
    return arm


@pytest.fixture(scope="session")
def repo_root() -> pathlib.Path:
    """The repository's root (docs, sweeps, benchmarks, analysis)."""
    return ROOT


def three_obstacle_field(xp=jnp, dtype=None) -> Scenario:
    """3 real obstacles (a static sphere near the start–goal line, a cylinder, a moving sphere crossing
    the path) and one padded slot; float64 by default (create inside ``jax.enable_x64`` for JAX)."""
    f = lambda a: xp.asarray(a, dtype=dtype or xp.float64)
    return Scenario(
        start=f([0.0, 0.0, 0.0]),
        goal=f([12.0, 0.5, 0.5]),
        obstacles=Obstacles(
            position=f([[4.0, 0.3, 0.0], [7.0, -1.5, 5.0], [9.0, 4.0, 0.2], [1e6, 1e6, 1e6]]),
            velocity=f([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-0.3, -0.6, 0.0], [0.0, 0.0, 0.0]]),
            radius=f([1.0, 0.8, 0.7, 0.0]),
            cylinder=xp.asarray([False, True, False, False]),
            valid=xp.asarray([True, True, True, False]),
        ),
    )


@pytest.fixture
def field_factory():
    """:func:`three_obstacle_field`, as a fixture for tests outside its module's directory."""
    return three_obstacle_field


def one_obstacle_scenario(goal_x: float, obstacle_x: float, radius: float) -> Scenario:
    """Start at the origin (2 m up), the goal and one vertical cylinder on the x axis."""
    return Scenario(start=jnp.asarray([0.0, 0.0, 2.0]), goal=jnp.asarray([goal_x, 0.0, 2.0]),
                    obstacles=Obstacles(position=jnp.asarray([[obstacle_x, 0.0, 2.0]]), velocity=jnp.zeros((1, 3)),
                                        radius=jnp.asarray([radius]), cylinder=jnp.asarray([True]),
                                        valid=jnp.asarray([True])))


def outcomes(scenario: Scenario, methods, t_max: float = 40.0) -> dict[str, dict[str, bool]]:
    """success / collision / stalled of one episode per planner (default gains, N = 10, I = 20)."""
    import jax

    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.engine import rollout
    from jaxapf.metrics import episode_metrics

    mpc, out = MPCConfig(horizon=10, iters=20), {}
    for method in methods:
        sim = SimConfig.from_flat(method=method, t_max=t_max)
        traj = jax.jit(rollout, static_argnums=(2, 3))(scenario, Gains(), sim, mpc)
        metrics = episode_metrics(traj, scenario, sim, ("success", "collision", "stalled"))
        out[method] = {k: bool(v) for k, v in metrics.items()}
    return out


def assert_same_episodes(a, b, dt: float, *, flips: int = 0, rtol: float = 1e-2, atol: float = 1e-2) -> None:
    """The metrics of the same episodes from two compiled programs (two engines, batch widths, device
    counts, CPUs) agree up to what rounding can move, and no more.

    Two programs that fuse, vectorise or shard differently round some operations apart, and the closed
    loop carries a last-bit difference along the episode (docs/testing.md). So: every outcome (a rate
    metric) is equal except on at most ``flips`` episodes, which the caller must justify (an episode on
    a knife edge); a metric counted in control steps (``Metric.per_step``) differs by at most one step
    (``dt`` for a time); any other float metric agrees to ``rtol``/``atol`` (NaN where NaN) on the
    episodes that end at the same step with the same outcomes (one step more of flight moves a path
    length by a whole step). ``a`` and ``b``: dicts of metric arrays or DataFrames of sweep rows;
    columns that are not metrics (ids, gains) must be equal.
    """
    import numpy as np

    from jaxapf.metrics import find_metric, is_metric

    names = list(a.keys()) if isinstance(a, dict) else list(a.columns)
    assert sorted(names) == sorted(b.keys() if isinstance(b, dict) else b.columns), "the same columns"
    col = lambda t, n: np.asarray(t[n])  # noqa: E731
    metrics = {n: find_metric(n) for n in names if is_metric(n)}  # single-UAV or swarm metrics
    rates = [n for n, m in metrics.items() if m.kind == "rate"]
    differ = np.zeros(np.shape(col(a, names[0])), bool)
    for n in rates:
        differ |= col(a, n) != col(b, n)
    assert differ.sum() <= flips, f"outcomes differ on {int(differ.sum())} episodes (allowed: {flips}): " + ", ".join(
        f"{n} {int((col(a, n) != col(b, n)).sum())}" for n in rates)
    same_end = ~differ
    if "steps" in names:
        same_end &= col(a, "steps") == col(b, "steps")
    for n in names:
        x, y = col(a, n), col(b, n)
        if n not in metrics:
            np.testing.assert_array_equal(x, y, err_msg=n)
        elif metrics[n].per_step:
            step = dt if metrics[n].unit == "s" else 1
            both = ~differ & np.isfinite(x.astype(float)) & np.isfinite(y.astype(float))
            gap = np.abs(x.astype(float) - y.astype(float))[both]
            assert np.all(gap <= step * (1 + 1e-6)), f"{n}: {gap.max()} apart, more than one step"
            np.testing.assert_array_equal(np.isnan(x[~differ].astype(float)), np.isnan(y[~differ].astype(float)),
                                          err_msg=n)
        elif metrics[n].kind != "rate":
            np.testing.assert_allclose(x[same_end], y[same_end], rtol=rtol, atol=atol, err_msg=n)


def changed(table: dict, **changes) -> dict:
    """A deep copy of the spec ``table`` with ``changes`` given by dotted keys (``"scenario.fields"``)."""
    import copy

    data = copy.deepcopy(table)
    for dotted, value in changes.items():
        *path, key = dotted.split(".")
        at = data
        for part in path:
            at = at.setdefault(part, {})
        at[key] = value
    return data


def package_calls(root: pathlib.Path, allowed=(), outside_io: bool = True):
    """``(file, call, name)`` of every call in the package's modules but ``allowed`` (and jaxapf/io, with
    ``outside_io``): what the tests that hold every write, read and CSV to jaxapf's own helpers walk."""
    import ast

    for path in sorted((root / "jaxapf").rglob("*.py")):
        rel = str(path.relative_to(root))
        if (outside_io and rel.startswith("jaxapf/io/")) or rel in allowed:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                f = node.func
                yield rel, node, f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""

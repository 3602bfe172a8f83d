"""A sweep's output under faults: concurrent writers, damaged parts, unwritable folders, Ctrl-C.

Each test asserts what a user relies on when publishing from a sweep: no row lost, doubled or
silently changed, and one plain line (never a traceback) for every refusal.
"""

import errno
import json
import os
import pathlib
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT

from jaxapf.cli import main
from jaxapf.io.lock import LOCK_NAME, OutputLock
from jaxapf.sweep import parse_spec, read_sweep, run_sweep
from jaxapf.sweep.output import part_files, verify_part
from jaxapf.validation import ConfigError

sys.path.insert(0, str(ROOT / "benchmarks"))
import faults  # noqa: E402  (the benchmark's program and sweep)
from faults import hooked, interpreters_own, program, startup_s  # noqa: E402

SPEC = {
    "name": "faults",
    "scenario": {"families": ["trap", "crossing"], "fields": 12, "seed": 3},
    "sim": {"t_max": 2.0, "horizon": 3, "iters": 3},
    "grid": {"k_rep": [5.0, 10.0]},
}
ROWS = 2 * 2 * 12
KEY = ["setting", "family", "field"]

SPEC_TOML = """name = "faults"
[scenario]
families = ["trap", "crossing"]
fields = 12
seed = 3
[sim]
t_max = 2.0
horizon = 3
iters = 3
[grid]
k_rep = [5.0, 10.0]
"""


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "faults.parquet"
    run_sweep(parse_spec(SPEC), out, chunk_fields=3, quiet=True)
    df, _ = read_sweep(out)
    return out, df


def _copy(src: pathlib.Path, dst: pathlib.Path) -> pathlib.Path:
    dst.mkdir()
    for p in src.iterdir():
        (dst / p.name).write_bytes(p.read_bytes())
    return dst


def _cli(args: list[str], tmp_path: pathlib.Path, **kw) -> subprocess.Popen:
    spec = tmp_path / "faults.toml"
    spec.write_text(SPEC_TOML)
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.Popen([sys.executable, "-m", "jaxapf", "sweep", str(spec), "--no-cache", "--quiet", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, **kw)


def _wait_for(predicate, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError
        time.sleep(0.05)


def _one_line(stderr: str) -> str:
    """The one line a refused or stopped run wrote (besides how far it had got: jaxapf.progress)."""
    from jaxapf.progress import without_progress

    lines = [line for line in without_progress(stderr).splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    return lines[0]


# --------------------------------------------------------------------------------------------
# one writer per output
# --------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_a_second_sweep_on_the_same_output_refuses_and_the_first_finishes(reference, tmp_path):
    out = tmp_path / "shared.parquet"
    first = _cli(["--out", str(out), "--chunk-fields", "3"], tmp_path)
    _wait_for(lambda: (out / LOCK_NAME).exists())
    second = _cli(["--out", str(out), "--chunk-fields", "4"], tmp_path)
    _, err2 = second.communicate(timeout=300)
    _, err1 = first.communicate(timeout=300)
    assert first.returncode == 0, err1
    assert second.returncode == 2
    line = _one_line(err2)
    assert f"is being written by pid {first.pid} on {socket.gethostname()}" in line and "one writer" in line
    df, meta = read_sweep(out)
    assert meta["complete"] and len(df) == ROWS and not df.duplicated(KEY).any()
    pd.testing.assert_frame_equal(df, reference[1])
    assert not (out / LOCK_NAME).exists()


def test_a_dead_writers_lock_file_does_not_block_the_next_run(reference, tmp_path, capsys):
    """A writer killed with ``kill -9`` leaves its lock file and owner note behind (from this host or
    another); the kernel released its lock, so the next run takes it without a word and resumes."""
    out = _copy(reference[0], tmp_path / "stale.parquet")
    for host in (socket.gethostname(), "another-host"):
        lock = {"pid": 1, "host": host, "since": time.time(), "command": "jaxapf sweep old.toml"}
        (out / LOCK_NAME).write_text(json.dumps(lock))
        result = run_sweep(parse_spec(SPEC), out, quiet=False)
        assert result.episodes == 0 and result.skipped == ROWS
        assert "lock" not in capsys.readouterr().err
        assert not (out / LOCK_NAME).exists()


def test_a_disk_that_fills_during_a_sweep_gives_one_line_keeps_every_finished_part_and_no_lock(
        reference, tmp_path, monkeypatch):
    """The old run ended in a traceback. Here: one line saying what was kept, no lock left behind, and
    the rerun on a disk with room completes the same rows."""
    import jaxapf.sweep.output as output

    real, writes = output.write_atomic, []

    def fills(path, write):
        if len(writes) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        writes.append(path)
        return real(path, write)

    monkeypatch.setattr(output, "write_atomic", fills)
    out = tmp_path / "full.parquet"
    with pytest.raises(ConfigError) as err:
        run_sweep(parse_spec(SPEC), out, chunk_fields=3, quiet=True)
    line = str(err.value)
    assert "No space left on device; 2 finished part(s) are kept" in line and "\n" not in line
    assert not (out / LOCK_NAME).exists() and len(part_files(out)) == 2
    monkeypatch.undo()
    run_sweep(parse_spec(SPEC), out, chunk_fields=3, quiet=True)
    df, meta = read_sweep(out)
    assert meta["complete"]
    pd.testing.assert_frame_equal(df, reference[1])


def test_the_lock_of_a_live_process_is_kept(tmp_path):
    with OutputLock(tmp_path):
        with pytest.raises(ConfigError, match="already being written by this process"):
            OutputLock(tmp_path).acquire()
        assert (tmp_path / LOCK_NAME).exists()
    assert not (tmp_path / LOCK_NAME).exists()


# --------------------------------------------------------------------------------------------
# every part verifiable
# --------------------------------------------------------------------------------------------

def test_a_truncated_part_is_named_and_repair_recomputes_exactly_it(reference, tmp_path):
    out = _copy(reference[0], tmp_path / "trunc.parquet")
    parts = part_files(out)
    victim = parts[len(parts) // 2]  # not the first part
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    with pytest.raises(ConfigError, match=rf"1 damaged part\(s\): {victim.name}: .*--repair"):
        run_sweep(parse_spec(SPEC), out, chunk_fields=3, quiet=True)
    with pytest.raises(ConfigError, match=victim.name):
        read_sweep(out)
    before = {p.name: p.stat().st_mtime_ns for p in parts if p != victim}
    rerun = []
    result = run_sweep(parse_spec(SPEC), out, chunk_fields=3, repair=True, quiet=True, after_part=rerun.append)
    assert [c.name for c in rerun] == [victim.name] and result.episodes == 2 * 3
    assert {p.name: p.stat().st_mtime_ns for p in part_files(out) if p.name != victim.name} == before
    pd.testing.assert_frame_equal(read_sweep(out)[0], reference[1])


def test_cli_names_the_damaged_part_with_the_remedy(reference, tmp_path, capsys):
    out = _copy(reference[0], tmp_path / "cli.parquet")
    victim = part_files(out)[-1]
    victim.write_bytes(victim.read_bytes()[:-7])
    spec = tmp_path / "faults.toml"
    spec.write_text(SPEC_TOML)
    rc = main(["sweep", str(spec), "--dry-run", "--no-cache", "--out", str(out), "--chunk-fields", "3"])
    err = capsys.readouterr().err
    assert rc == 2 and victim.name in _one_line(err) and "--repair" in err


def test_every_bit_flip_is_refused_or_harmless(reference, tmp_path):
    """60 single-bit flips at random offsets of random parts: reading either refuses, naming the
    part, or returns exactly the reference rows. None changes a number silently."""
    rng = np.random.default_rng(0)
    out = _copy(reference[0], tmp_path / "flips.parquet")
    parts = part_files(out)
    refused = harmless = 0
    for _ in range(60):
        victim = parts[rng.integers(len(parts))]
        data = bytearray(victim.read_bytes())
        at = int(rng.integers(len(data)))
        data[at] ^= 1 << int(rng.integers(8))
        original = victim.read_bytes()
        victim.write_bytes(bytes(data))
        try:
            df, _ = read_sweep(out)
        except ConfigError as err:
            assert victim.name in str(err)
            assert verify_part(victim) is not None
            refused += 1
        else:
            pd.testing.assert_frame_equal(df, reference[1])
            harmless += 1
        victim.write_bytes(original)
    assert refused + harmless == 60 and refused > 0


@pytest.mark.slow
def test_every_flip_in_a_parts_footer_is_a_damaged_part_or_harmless(reference, tmp_path):
    """1,500 single-bit flips in one part's footer (its schema, column names, statistics, metadata): verify
    names the part or the rows read back exactly, and nothing raises. A flip in a column name used to raise
    UnicodeDecodeError in verify, resume, --repair and report; one in a column's integer width,
    ArrowNotImplementedError."""
    import struct

    from jaxapf.sweep.meta import read_meta
    from jaxapf.sweep.output import part_record, read_part

    part = part_files(reference[0])[0]
    original = part.read_bytes()
    footer = struct.unpack("<I", original[-8:-4])[0] + 8
    expected = read_part(part).to_pandas()
    victim = tmp_path / part.name
    rng = np.random.default_rng(1)
    name = original.find(b"min_clearance", len(original) - footer)  # the flip: a column name's first byte
    flips = [(name, 7)] + [(len(original) - footer + int(rng.integers(footer)), int(rng.integers(8)))
                           for _ in range(1500)]
    refused = 0
    for at, bit in flips:
        data = bytearray(original)
        data[at] ^= 1 << bit
        victim.write_bytes(bytes(data))
        why = verify_part(victim)  # never raises
        part_record(victim)
        try:
            read_meta(victim)
        except ConfigError:
            pass
        if why is None:
            assert read_part(victim).to_pandas().equals(expected), (at, bit)
        else:
            assert why.startswith(part.name) and "\n" not in why
            refused += 1
        if (at, bit) == (name, 7):
            assert "unreadable (UnicodeDecodeError" in why
    assert refused > 500


# --------------------------------------------------------------------------------------------
# unwritable outputs and interruptions: one line, before any work
# --------------------------------------------------------------------------------------------

@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_a_read_only_output_folder_is_refused_before_any_work(tmp_path, capsys):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    spec = tmp_path / "faults.toml"
    spec.write_text(SPEC_TOML)
    try:
        rc = main(["sweep", str(spec), "--no-cache", "--out", str(folder / "x.parquet")])
    finally:
        folder.chmod(0o755)
    assert rc == 2 and "cannot be written: Permission denied" in _one_line(capsys.readouterr().err)


@pytest.mark.parametrize("command", ["sweep", "report", "simulate"])
def test_a_read_only_file_system_is_one_line(command, tmp_path, capsys, monkeypatch):
    """The same refusal on a read-only file system (EROFS, faked: tests may run as root)."""
    real = os.open

    def refuse(path, flags, *args, **kwargs):
        if flags & (os.O_WRONLY | os.O_RDWR):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", refuse)
    spec = tmp_path / "faults.toml"
    spec.write_text(SPEC_TOML)
    out = str(tmp_path / "out")
    argv = {"sweep": ["sweep", str(spec), "--no-cache", "--out", out],
            "report": ["report", str(tmp_path / "missing.parquet"), "--out", out],
            "simulate": ["simulate", "--family", "trap", "--out", out]}[command]
    rc = main(argv)
    assert rc == 2 and "cannot be written: Read-only file system" in _one_line(capsys.readouterr().err)


def test_output_paths_that_are_files_are_refused(tmp_path, capsys):
    spec = tmp_path / "faults.toml"
    spec.write_text(SPEC_TOML)
    taken = tmp_path / "taken"
    taken.write_text("mine")
    assert main(["sweep", str(spec), "--no-cache", "--out", str(taken)]) == 2
    assert "is a file" in _one_line(capsys.readouterr().err)
    assert main(["report", str(tmp_path / "missing.parquet"), "--out", str(taken)]) == 2
    assert "is a file" in _one_line(capsys.readouterr().err)
    assert taken.read_text() == "mine"


@pytest.mark.slow
@pytest.mark.parametrize("sig, status, word", [(signal.SIGINT, 130, "interrupted"),
                                               (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_a_signal_ends_a_sweep_with_one_line_and_the_rerun_completes_it(reference, tmp_path, sig, status, word):
    """Ctrl-C, and SIGTERM (a scheduler's time limit), which used to end a run without a word."""
    out = tmp_path / "signal.parquet"
    run = _cli(["--out", str(out), "--chunk-fields", "1"], tmp_path)
    _wait_for(lambda: out.exists() and len(part_files(out)) >= 2)
    run.send_signal(sig)
    _, err = run.communicate(timeout=120)
    if run.returncode == 0:
        pytest.skip("the sweep finished before the signal arrived")
    assert run.returncode == status
    line = _one_line(err)
    assert line.startswith(f"jaxapf sweep: {word}; ") and "finished part(s) are kept" in line
    assert "rerun the same command to resume" in line
    kept = part_files(out)
    assert kept and all(verify_part(p) is None for p in kept)
    assert not (out / LOCK_NAME).exists() and not any(p.name.startswith(".part-") for p in out.iterdir())
    rerun = _cli(["--out", str(out), "--chunk-fields", "1"], tmp_path)
    _, err = rerun.communicate(timeout=300)
    assert rerun.returncode == 0, err
    df, meta = read_sweep(out)
    assert meta["complete"] and not df.duplicated(KEY).any()
    pd.testing.assert_frame_equal(df, reference[1])


def test_only_a_signal_before_the_hook_is_pythons_own(tmp_path):
    """The classifier of the signal tests and benchmarks/faults.py. Whether jaxapf's hook is in place is read
    from /proc (a caught SIGTERM): not in a bare interpreter, nor in one importing the library, but in the
    program once it runs. Before the hook, anything CPython does is its own (in CI it lost a SIGINT, the run
    ending 0, silently or after "Exception ignored"); after it, nothing is. Where /proc cannot tell, only an
    exit or Python's report of an ignored interrupt from the interpreter's start counts."""
    bare = subprocess.Popen([sys.executable, "-c", "import jaxapf.cli, time; print('ready', flush=True); "
                             "time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    try:
        assert bare.stdout.readline().strip() == "ready"
        assert hooked(bare.pid) is False  # a library import installs nothing
    finally:
        bare.kill()
        bare.wait()
    spec = tmp_path / "faults.toml"
    spec.write_text(SPEC_TOML)
    run = subprocess.Popen(program("module") + ["sweep", str(spec), "--out", str(tmp_path / "o"), "--no-cache",
                                                "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    seen = []
    _wait_for(lambda: seen.append(hooked(run.pid)) or seen[-1] is True or run.poll() is not None, timeout=300)
    run.communicate(timeout=300)
    assert run.returncode == 0 and seen[-1] is True and hooked(run.pid) is None  # in place while it ran; ended
    for rc, err in ((0, ""), (0, "Exception ignored in: ...\nKeyboardInterrupt: "), (-2, ""), (1, "Traceback ...")):
        assert interpreters_own(False, 5.0, 0.1, rc, err) and not interpreters_own(True, 0.01, 0.1, rc, err)
    ignored = ('Exception ignored in: <function _get_module_lock.<locals>.cb at 0x7f0da0b872e0>\n'
               'Traceback (most recent call last):\n  File "<frozen importlib._bootstrap>", line 207, in cb\n'
               'KeyboardInterrupt: \n')
    assert interpreters_own(None, 0.02, 0.1, 0, ignored)
    assert not interpreters_own(None, 0.2, 0.1, 0, ignored)  # past the start: jaxapf's hook was in place
    assert not interpreters_own(None, 0.02, 0.1, 0, ignored.replace("<frozen importlib._bootstrap>", "/x/jaxapf/a.py"))
    assert not interpreters_own(None, 0.02, 0.1, 0, ignored.replace("KeyboardInterrupt", "ValueError"))
    assert not interpreters_own(None, 0.02, 0.1, 0, ignored + ignored)
    assert not interpreters_own(None, 0.02, 0.1, 0, "")  # cannot tell a lost signal from one that came too late
    assert interpreters_own(None, 0.02, 0.1, -2, "") and interpreters_own(None, 0.02, 0.1, 1, "Traceback ...")
    assert interpreters_own(None, 3.0, 0.1, 1, "Fatal Python error: init_import_site: Failed to import the site")
    assert not interpreters_own(None, 3.0, 0.1, 1, "Traceback ...")


@pytest.mark.slow
def test_a_signal_while_the_command_starts_is_one_line(tmp_path):
    """Ctrl-C in the first second (imports, the catalogue, JAX's start) used to print a traceback, crash the
    process (SIGSEGV, C++'s terminate, when raised inside an extension module's import) or be swallowed by
    JAX's garbage-collection callback (the run went on to exit 0). Only a signal while the interpreter itself
    starts (before jaxapf's hook is in place, read from /proc) is Python's own: it ends the process, or Python
    loses it (raised in one of its own callbacks, python/cpython#95959; about 1 in 400 signals in the first
    80 ms under load) and the command runs to its end, its output complete."""
    startup = 2 * startup_s() + 0.02
    spec = tmp_path / "faults.toml"
    spec.write_text(SPEC_TOML)
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    for i, delay in enumerate(np.linspace(0.03, 1.2, 14)):
        run = subprocess.Popen(program("script" if i % 2 else "module") + [
            "sweep", str(spec), "--out", str(tmp_path / f"early-{i}"), "--no-cache", "--quiet"], stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True, env=env)
        time.sleep(float(delay))
        hook = faults.interrupt(run)
        _, err = run.communicate(timeout=120)
        if run.returncode != 130 and interpreters_own(hook, float(delay), startup, run.returncode, err):
            if run.returncode == 0:  # Python lost it and ran the command to its end: its output is complete
                assert read_sweep(tmp_path / f"early-{i}")[1]["complete"], err
            continue
        assert run.returncode == 130, (delay, err)
        assert _one_line(err).startswith("jaxapf"), err


def _wait(seconds: float) -> None:
    """Sleep ``seconds`` in steps of 10 ms: an interrupt made pending in the main thread (not a signal, which
    would end a sleep) is raised between two steps, not after the whole of it."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.01)


def test_a_signal_inside_an_import_waits_for_its_end_and_a_swallowed_one_is_raised_again(tmp_path, monkeypatch):
    """The handler of the command line holds a signal that comes while a module is imported (raised inside an
    extension module's initialisation, it crashed the process) and raises it once the import ended; an
    interrupt Python reported as "Exception ignored" (JAX's gc callback) is raised again in the main thread."""
    import importlib
    import types

    from jaxapf.cli import stops

    (tmp_path / "signalled_during_import.py").write_text(
        "import signal, time\nfrom jaxapf.cli.stops import on_signal\n"
        "import sys\non_signal(signal.SIGINT, sys._getframe())\nDONE = True\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    # SIGINT handled as the command line handles it: a held signal goes to whatever handles SIGINT then, and an
    # earlier test in this worker may have left it ignored
    previous = signal.signal(signal.SIGINT, stops.on_signal)
    try:
        with pytest.raises(KeyboardInterrupt):
            module = importlib.import_module("signalled_during_import")  # held: the import completes
            assert module.DONE
            _wait(5.0)  # then it is raised here, at the latest
        assert "signalled_during_import" in sys.modules
        with pytest.raises(stops.Terminated):
            stops.on_signal(signal.SIGTERM, sys._getframe())  # outside an import: at once
        hook = stops.unraisable(lambda report: None)
        with pytest.raises(KeyboardInterrupt):
            hook(types.SimpleNamespace(exc_value=KeyboardInterrupt()))
            _wait(5.0)
    finally:
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)


@pytest.mark.parametrize("sig, status, word", [(signal.SIGINT, 130, "interrupted"),
                                               (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_a_stop_that_something_swallows_still_ends_the_program_with_its_line(tmp_path, sig, status, word):
    """A signal raised where a library swallows it whole (``except BaseException``) let the command run to its
    end and exit 0 (seen once in ~100 early SIGINTs under load): the program still ends with the stop's line
    and status, saying the output is complete. The same program without a signal exits 0."""
    script = tmp_path / "swallowing.py"
    script.write_text(
        "import os, signal, sys, time\n"
        "from jaxapf.cli import commands, program\n"
        "def swallowing_main():\n"
        "    try:\n"
        "        if True:\n"
        f"            os.kill(os.getpid(), {int(sig)})\n"
        "            time.sleep(5)\n"
        "    except BaseException:\n"
        "        pass\n"
        "    return 0\n"
        "commands.main = swallowing_main\n"
        "sys.exit(program.console())\n")
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert run.returncode == status, run.stderr
    line = _one_line(run.stderr)
    assert line == f"jaxapf: {word}; the command had finished before it stopped: its output is complete"
    script.write_text(script.read_text().replace("if True:", "if False:"))
    quiet = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert quiet.returncode == 0 and not quiet.stderr, quiet.stderr


@pytest.mark.parametrize("command", ["report", "simulate", "compare"])
def test_ctrl_c_is_one_line_saying_what_was_kept(command, tmp_path, capsys, monkeypatch, reference):
    """Ctrl-C in any command: one line, status 130, no traceback."""
    import jaxapf.compare.protocol
    import jaxapf.report
    import jaxapf.simulate

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    target = {"report": (jaxapf.report, "build_report"), "simulate": (jaxapf.simulate, "simulate_runs"),
              "compare": (jaxapf.compare.protocol, "select")}[command]
    monkeypatch.setattr(*target, interrupt)
    spec = tmp_path / "c.toml"
    spec.write_text('methods = ["basic", "direction"]\n[selection]\nfamilies = ["trap"]\nseeds = [1, 2, 3]\n'
                    'budget = 8\n[test]\nfamilies = ["trap"]\nfields = 2\n')
    argv = {"report": ["report", str(reference[0]), "--out", str(tmp_path / "r")],
            "simulate": ["simulate", "--family", "trap", "--out", str(tmp_path / "s")],
            "compare": ["compare", str(spec), "--out", str(tmp_path / "c"), "--no-cache"]}[command]
    assert main(argv) == 130
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"jaxapf {command}: interrupted; ")
    if command == "compare":
        assert "finished selections and test parts are kept" in line and not (tmp_path / "c" / LOCK_NAME).exists()


@pytest.mark.parametrize("command", ["sweep", "tune", "compare"])
@pytest.mark.parametrize("bad", ["directory", "not utf-8"])
def test_an_unreadable_spec_file_is_one_line(command, bad, tmp_path, capsys):
    """Every command reads its TOML through one reader (jaxapf.validation.read_toml_file)."""
    path = tmp_path / "spec.toml"
    if bad == "directory":
        path.mkdir()
    else:
        path.write_bytes(b"\xff\xfename = 1\n")
    assert main([command, str(path), "--out", str(tmp_path / "out")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == (f"jaxapf {command}: error: spec file {str(path)!r} is a directory" if bad == "directory" else
                    f"jaxapf {command}: error: spec file {str(path)!r} is not valid TOML: 'utf-8' codec can't decode "
                    "byte 0xff in position 0: invalid start byte")


SIGINT_TOML = faults.SPEC_TOML.replace("fields = 16", "fields = 192")  # faults.py's sweep, ~10 s a run warm
#: The moments fall in 0 … MOMENTS_S seconds of a run: the interpreter's start, jaxapf's imports, loading the
#: programs from the cache and about 2 s of computing, every phase where an interrupt was once lost or crashed.
MOMENTS_S = 4.0


def _sigint_stream(stream: int, trials: int, spec: pathlib.Path, cache: pathlib.Path, tmp: pathlib.Path,
                   startup: float) -> dict:
    """``trials`` runs of the program, each sent SIGINT at a random moment in 0-MOMENTS_S s, resuming one output until
    it is complete, then the next; what each ended with."""
    rng = np.random.default_rng(stream)
    seen = {"stopped": 0, "finished": 0, "interpreter": 0, "outputs": [], "bad": []}
    out = None
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    for i in range(trials):
        if out is None:
            out = tmp / f"sigint-{stream}-{i}.parquet"
            seen["outputs"].append(out)
        moment = float(rng.uniform(0.0, MOMENTS_S))
        argv = program("script" if i % 2 else "module") + [
            "sweep", str(spec), "--out", str(out), "--cache-dir", str(cache), "--quiet", "--chunk-fields", "2"]
        run = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        time.sleep(moment)
        hook = faults.interrupt(run)
        stdout, stderr = run.communicate(timeout=300)
        lines = [line for line in stderr.splitlines() if line.strip()]
        if run.returncode == 0 and stdout.startswith("sweep faults:") and not lines:
            seen["finished"] += 1  # done before the signal came
            out = None
        elif (run.returncode == 130 and len(lines) == 1 and "interrupted; " in lines[0]
              and lines[0].startswith("jaxapf")):
            seen["stopped"] += 1
        elif interpreters_own(hook, moment, startup, run.returncode, stderr):
            seen["interpreter"] += 1  # the interpreter itself was starting (on a loaded machine past `startup`)
            out = None if run.returncode == 0 else out  # Python lost it: the command ran to its end
        else:
            seen["bad"].append((moment, run.returncode, stderr[-2000:]))
    return seen


@pytest.mark.slow
def test_ctrl_c_at_fifty_random_moments_is_one_line_and_the_resumed_rows_are_exact(tmp_path):
    """SIGINT at 50 random moments in 0-4 s of `jaxapf sweep` (the script and python -m jaxapf): one line and
    status 130 every time, never a traceback or an exit 0 (but Python's own, test above); every output resumed
    to completion holds the one-process rows bit for bit. (JAX's garbage-collection callback used to swallow
    the interrupt, the run went on to exit 0; an interrupt inside an import crashed the process; tracebacks
    while starting.)
    Only a signal while the interpreter itself starts (before any line of jaxapf) is Python's to handle."""
    import concurrent.futures

    spec = tmp_path / "sigint.toml"
    spec.write_text(SIGINT_TOML)
    cache = tmp_path / "cache"
    startup = 2 * startup_s() + 0.02
    with concurrent.futures.ThreadPoolExecutor(2) as pool:  # two streams side by side: 25 moments each
        streams = list(pool.map(lambda s: _sigint_stream(s, 25, spec, cache, tmp_path, startup), (0, 1)))
    bad = [b for s in streams for b in s["bad"]]
    assert not bad, bad
    assert sum(s["stopped"] + s["finished"] + s["interpreter"] for s in streams) == 50
    assert sum(s["stopped"] for s in streams) >= 35  # most moments fall while it runs
    reference = tmp_path / "reference.parquet"
    import tomllib

    run_sweep(parse_spec(tomllib.loads(SIGINT_TOML)), reference, chunk_fields=16, quiet=True)
    expected = read_sweep(reference)[0]
    for out in (o for s in streams for o in s["outputs"]):
        done = subprocess.run(program("module") + ["sweep", str(spec), "--out", str(out), "--cache-dir", str(cache),
                                                    "--quiet", "--chunk-fields", "2"],
                              capture_output=True, text=True, env={**os.environ, "JAX_PLATFORMS": "cpu"}, timeout=300)
        assert done.returncode == 0, done.stderr
        df, meta = read_sweep(out)
        assert meta["complete"] and not df.duplicated(KEY).any()
        pd.testing.assert_frame_equal(df, expected)


@pytest.mark.slow
@pytest.mark.parametrize("sig, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_stops_a_run_at_once_not_after_its_chunk(sig, status, tmp_path):
    """While the main thread waited inside XLA for a chunk (or its compilation), Python could not run the signal
    handler: the stop came only after the chunk, 7-9 s later here, never on an episode of 10^6 steps."""
    spec = tmp_path / "long.toml"
    spec.write_text(SPEC_TOML.replace("t_max = 2.0", "t_max = 3000.0"))  # one chunk of 30,000 steps: ~10 s
    run = subprocess.Popen(program("script") + ["sweep", str(spec), "--out", str(tmp_path / "o"), "--no-cache",
                                                "--quiet", "--chunk-fields", "12"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           env={**os.environ, "JAX_PLATFORMS": "cpu"})
    lock, deadline = tmp_path / "o" / ".lock", time.monotonic() + 120
    while not lock.exists() and run.poll() is None and time.monotonic() < deadline:  # started on any machine
        time.sleep(0.05)
    time.sleep(2.5)  # the chunk compiling or computing: the main thread waits inside XLA
    sent = time.monotonic()
    run.send_signal(sig)
    _, err = run.communicate(timeout=120)
    assert run.returncode == status, err
    assert time.monotonic() - sent < 2.0
    assert "0 finished part(s) are kept" in _one_line(err)


@pytest.mark.slow
def test_ctrl_c_on_a_report_leaves_no_process_and_one_line(reference, tmp_path):
    """The report's worker process outlived a stopped report (and kept its output open), and printed its own
    traceback when Ctrl-C reached the whole process group."""
    for moment in (1.0, 2.0, 3.0):
        run = subprocess.Popen(program("script") + [
            "report", str(reference[0]), "--out", str(tmp_path / f"r{moment}"), "--resamples", "100", "--gallery", "2",
            "--heatmap", "none", "--no-cache", "--baseline", "setting=0"], stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True, env={**os.environ, "JAX_PLATFORMS": "cpu"}, start_new_session=True)
        time.sleep(moment)
        os.killpg(run.pid, signal.SIGINT)  # as a terminal's Ctrl-C: to every process of the group
        _, err = run.communicate(timeout=120)  # returns only once every process holding the pipes is gone
        if run.returncode == 0:
            continue  # finished first
        assert run.returncode == 130 and _one_line(err).startswith("jaxapf report: interrupted"), err
        # no process of the report left running: an exited child waiting for init to reap it (Z) is none, and one
        # still in its exit (shown as [python3.11] once its memory is released) gets 10 s to finish it
        for _ in range(100):
            session = subprocess.run(["ps", "-s", str(run.pid), "-o", "stat=,args="], capture_output=True, text=True)
            live = [line for line in session.stdout.splitlines() if line.strip() and not line.lstrip().startswith("Z")]
            if not live:
                break
            time.sleep(0.1)
        assert not live, live


@pytest.mark.slow
def test_the_fault_classes_of_reading_find_nothing_broken():
    """benchmarks/faults.py's classes of names jaxapf reads, each at its smallest full round (every command of
    a class once): a part, tune's checkpoint and a compare selection planted; parts swapped under merge and
    report; forged stored specs; mixed versions; crafted owner notes. Everything that must be zero is."""
    kinds = ["planted read", "swapped part", "forged spec", "mixed versions", "owner note"]
    result = faults.run_faults(only=kinds, reads_n=6, swaps_n=2, forged_n=4, versions_n=4, notes_n=7)
    assert faults.failures(result) == 0, {k: result[k] for k in kinds}
    assert result["planted read"]["refused"] + result["planted read"]["ran"] == 6
    assert result["forged spec"]["refused"] == 4 and result["mixed versions"]["refused"] == 4
    assert result["owner note"]["refused"] == 7

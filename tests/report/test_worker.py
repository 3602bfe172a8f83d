"""No process outlives its command: the report's second process ends when the report's process dies,
however it dies (``kill -9``, SIGHUP), and two reports into one folder are refused like two tunes."""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest
from cli_capture import capture

from jaxapf.cli import main
from jaxapf.io.lock import OutputLock
from jaxapf.sweep import parse_spec, run_sweep

SPEC = {"name": "worker", "scenario": {"families": ["trap"], "fields": 4, "seed": 4},
        "sim": {"t_max": 1.0, "horizon": 3, "iters": 3}, "grid": {"k_rep": [5.0, 10.0]}}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("worker") / "ds"
    run_sweep(parse_spec(SPEC), out, quiet=True)
    return out


def _children(pid: int) -> set[int]:
    """Every process whose parent is ``pid`` (from /proc)."""
    found = set()
    for entry in pathlib.Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.add(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGHUP])
def test_the_reports_worker_ends_when_the_report_dies(dataset, tmp_path, signum):
    report = subprocess.Popen([sys.executable, "-m", "jaxapf", "report", str(dataset), "--out", str(tmp_path / "r"),
                               "--baseline", "setting=0", "--gallery", "2", "--resamples", "200"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    give_up = time.monotonic() + 60
    children: set[int] = set()
    while not children and report.poll() is None and time.monotonic() < give_up:
        time.sleep(0.2)
        children = _children(report.pid)
    assert children, "the report started no second process"
    time.sleep(2.0)  # the worker is importing or drawing: the moment a user's kill or hang-up comes
    os.kill(report.pid, signum)
    report.wait(timeout=30)
    gone = time.monotonic() + 5.0
    while any(_alive(c) for c in children) and time.monotonic() < gone:
        time.sleep(0.05)
    left = [c for c in children if _alive(c)]
    for c in left:
        os.kill(c, signal.SIGKILL)
    assert left == [], f"{len(left)} process(es) of the report outlived it"


def test_a_second_report_into_a_locked_folder_is_refused_in_one_line(dataset, tmp_path):
    with OutputLock(tmp_path / "r"):
        rc, out, err = capture(main, ["report", str(dataset), "--out", str(tmp_path / "r"), "--gallery", "0",
                                      "--baseline", "setting=0"])
    assert rc == 2 and "is already being written by this process" in err and len(err.strip().splitlines()) == 1, err

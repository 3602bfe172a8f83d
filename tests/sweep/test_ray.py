"""`jaxapf sweep SPEC --ray [ADDRESS]`: the chunks run as Ray tasks on a local two-worker cluster and the
rows are a one-process run's, bit for bit, also when a worker is killed with SIGKILL mid-run; a task
that fails for good stops the run in one line keeping every finished part; bad options are one line."""

from __future__ import annotations

import os
import pathlib
import re
import signal
import subprocess
import sys

import pandas as pd
import pytest
from cli_capture import capture
from conftest import ROOT
from test_shards import SPEC, _spec

from jaxapf.cli import main
from jaxapf.sweep import read_sweep, run_sweep
from jaxapf.sweep.cluster import RayCluster
from jaxapf.validation import ConfigError, Interrupted

sys.path.insert(0, str(ROOT / "benchmarks"))
from ray_cluster import busy_workers  # noqa: E402  (the benchmark's: Ray titles a busy worker ray::ChunkWorker.run)


def killer(killed: list[int]):
    """An ``after_part`` that kills one busy worker with SIGKILL after the first part it can."""
    def after(chunk):
        if not killed and (pids := busy_workers()):
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])
    return after


def _spec_file(folder: pathlib.Path) -> pathlib.Path:
    import json

    lines = [f"name = {json.dumps(SPEC['name'])}"]
    for table in ("scenario", "sim", "grid"):
        lines += [f"[{table}]"] + [f"{k} = {json.dumps(v)}" for k, v in SPEC[table].items()]
    (folder / "shards.toml").write_text("\n".join(lines) + "\n")
    return folder / "shards.toml"


@pytest.fixture(scope="module")
def cluster():
    """A local Ray cluster with two worker slots, started by this test process; its address for others."""
    import ray

    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR")
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "ref.parquet"
    run_sweep(_spec(), out, chunk_fields=3, quiet=True)
    return read_sweep(out)[0]


@pytest.mark.slow
def test_a_worker_killed_mid_run_loses_and_doubles_nothing(cluster, reference, tmp_path):
    killed: list[int] = []
    result = run_sweep(_spec(), tmp_path / "out", chunk_fields=3, quiet=True, ray=RayCluster(),
                       after_part=killer(killed))
    assert killed, "no worker was busy to kill"
    assert result.episodes == len(reference) and result.parts == 16
    rc, stdout, _ = capture(main, ["sweep", "verify", str(tmp_path / "out")])
    assert rc == 0, stdout
    pd.testing.assert_frame_equal(read_sweep(tmp_path / "out")[0], reference)


@pytest.mark.slow
def test_a_task_failing_for_good_stops_in_one_line_and_a_rerun_resumes(cluster, reference, tmp_path):
    out, killed = tmp_path / "out", []
    with pytest.raises(ConfigError, match=r"chunk part-v\d+-\w+-f\d+-\d+\.parquet failed on the Ray cluster: its "
                                          r"worker died 1 time\(s\) \(.*\); "
                                          r"\d+ finished part\(s\) are kept in .*rerun the same command"):
        run_sweep(_spec(), out, chunk_fields=3, quiet=True, ray=RayCluster(retries=0), after_part=killer(killed))
    assert killed

    def stop(chunk):
        raise KeyboardInterrupt

    with pytest.raises(Interrupted, match="finished part"):  # Ctrl-C: the tasks in flight are cancelled
        run_sweep(_spec(), out, chunk_fields=3, quiet=True, ray=RayCluster(), after_part=stop)
    again = run_sweep(_spec(), out, chunk_fields=3, quiet=True, ray=RayCluster())
    assert again.skipped > 0 and again.episodes + again.skipped == len(reference)
    pd.testing.assert_frame_equal(read_sweep(out)[0], reference)


@pytest.mark.slow
def test_the_cli_runs_on_a_cluster_at_its_address(cluster, reference, tmp_path):
    spec = _spec_file(tmp_path)
    out = tmp_path / "out.parquet"
    cmd = [sys.executable, "-m", "jaxapf", "sweep", str(spec), "--out", str(out), "--chunk-fields", "3",
           "--cache-dir", str(tmp_path / "xla"), "--ray", cluster]
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    dry = subprocess.run(cmd + ["--dry-run"], env=env, capture_output=True, text=True, timeout=300)
    assert dry.returncode == 0, dry.stderr
    assert "16 to run (one Parquet part each), on 1 device(s), vmap width 16" in dry.stdout
    run = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert f"sweep shards: {len(reference)} episodes in" in run.stdout
    assert "Traceback" not in run.stderr
    pd.testing.assert_frame_equal(read_sweep(out)[0], reference)
    again = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and f"0 episodes ({len(reference)} already done)" in again.stdout


@pytest.mark.slow
def test_a_plugins_own_failure_on_a_worker_is_one_line_saying_where(cluster, tmp_path):
    """A plugin planner whose own code fails while a worker traces it: the driver's line names the plugin, its
    file, line and function (the worker's traceback, which Ray sends as text), and what was kept."""
    from test_extending import BROKEN, MISTAKES

    spec = tmp_path / "broken.toml"
    spec.write_text(f'name = "m"\nplugins = ["{MISTAKES}"]\n[scenario]\nfamilies = ["trap"]\nfields = 2\n'
                    '[sim]\nt_max = 0.5\nhorizon = 3\niters = 2\nmethod = "broken"\n')
    cmd = [sys.executable, "-m", "jaxapf", "sweep", str(spec), "--out", str(tmp_path / "out"), "--quiet",
           "--cache-dir", str(tmp_path / "xla"), "--ray", cluster]
    run = subprocess.run(cmd, env={**os.environ, "JAX_PLATFORMS": "cpu"}, capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "Traceback" not in run.stderr, run.stderr
    assert re.search(rf"chunk part-\S+ failed on the Ray cluster: the plugin {MISTAKES.name} failed at "
                     rf"{MISTAKES.name}:{BROKEN} in __call__: AttributeError: .*; 0 finished part\(s\) are kept",
                     run.stderr), run.stderr


@pytest.mark.parametrize("flags, message", [
    (["--ray-cpus", "2"], "--ray-cpus and --ray-gpus size the workers of --ray; give --ray too"),
    (["--ray", "--ray-cpus", "0"], "--ray-cpus and --ray-gpus are both 0"),
    (["--ray", "--ray-gpus", "-1"], "--ray-gpus = -1.0 is out of range"),
    (["--ray", "--shard", "0/2"], "--ray and --shard: Ray deals the chunks itself"),
    (["--ray", "--shard", "0/2", "--dry-run"], "--ray and --shard: Ray deals the chunks itself"),
    (["--ray", "--devices", "2"], "--devices = 2: with --ray each task runs on one device"),
    (["--ray", "127.0.0.1:1"], "--ray 127.0.0.1:1: nothing answers there"),
])
def test_ray_options_are_checked_in_one_line(tmp_path, flags, message):
    rc, stdout, stderr = capture(main, ["sweep", str(_spec_file(tmp_path)), "--out", str(tmp_path / "o"), *flags])
    assert rc == 2 and message in stderr and "Traceback" not in stderr, stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("server", ["silent", "http"])
def test_a_port_that_answers_but_is_not_ray_is_refused_in_one_line(server, tmp_path, monkeypatch):
    """Ray hung for more than 120 s with its C++ warnings on a port that answered TCP but was not Ray."""
    import socket
    import threading

    import jaxapf.sweep.cluster

    monkeypatch.setattr(jaxapf.sweep.cluster, "PROBE_TIMEOUT_S", 1.0)
    listener = socket.create_server(("127.0.0.1", 0))
    held = []

    def serve():
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            if server == "http":
                conn.recv(64)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
                conn.close()
            else:
                held.append(conn)  # accepts and never answers

    threading.Thread(target=serve, daemon=True).start()
    address = f"127.0.0.1:{listener.getsockname()[1]}"
    try:
        rc, _, stderr = capture(main, ["sweep", str(_spec_file(tmp_path)), "--out", str(tmp_path / "o"), "--ray",
                                       address])
    finally:
        listener.close()
    assert rc == 2 and stderr.count("\n") == 1, stderr
    why = "(it answered, but not in gRPC (HTTP/2))" if server == "http" else "(no answer within 1 s)"
    assert f"--ray {address}: something answers there, but not as a Ray cluster does {why}" in stderr
    assert not (tmp_path / "o").exists()


def test_without_ray_installed_the_option_says_how_to_get_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    rc, _, stderr = capture(main, ["sweep", str(_spec_file(tmp_path)), "--out", str(tmp_path / "o"), "--ray"])
    assert rc == 2 and "--ray needs Ray: pip install 'jaxapf[ray]'" in stderr


@pytest.mark.slow
def test_a_task_no_node_can_run_is_refused_not_left_waiting(cluster, tmp_path):
    with pytest.raises(ConfigError, match=r"no node of the cluster has 1 CPU\(s\) and 1 GPU\(s\) for one worker"):
        run_sweep(_spec(), tmp_path / "out", chunk_fields=3, quiet=True, ray=RayCluster(gpus=1))
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


@pytest.mark.slow
def test_the_parts_record_a_workers_versions(cluster, tmp_path):
    from jaxapf.sweep.meta import read_meta
    from jaxapf.sweep.output import part_files

    run_sweep(_spec(), tmp_path / "out", chunk_fields=6, quiet=True, ray=RayCluster())
    meta = read_meta(part_files(tmp_path / "out")[0])
    assert meta["versions"]["device"].startswith("cpu") and meta["versions"]["device_count"] == "1"


@pytest.mark.slow
def test_a_worker_that_cannot_start_says_why_in_one_line(cluster):
    """A plugin missing on a worker's node: the driver's error names it, without Ray's process ids."""
    from jaxapf.sweep.cluster import RaySession

    with RaySession(RayCluster()) as session:
        session.settings["plugins"] = [("lost.py", "/nonexistent/lost.py")]
        with pytest.raises(ConfigError) as err:
            session.probe()
    message = str(err.value)
    assert message.startswith("--ray: a worker could not start JAX (plugin = 'lost.py': no such file")
    assert "\n" not in message and "pid=" not in message


def test_the_sweep_page_states_the_ray_backends_own_numbers():
    """docs/sweep.md's "A Ray cluster" quotes the retries per chunk and the chunks in flight per worker:
    they are the code's."""
    from conftest import ROOT

    from jaxapf.sweep.cluster import IN_FLIGHT_PER_SLOT

    text = " ".join((ROOT / "docs" / "sweep.md").read_text().split())
    words = {1: "one", 2: "two", 3: "three", 4: "four"}
    assert f"a chunk at most {RayCluster().retries} times again" in text
    assert f"{words[IN_FLIGHT_PER_SLOT]} are in flight per worker" in text


_GPU_WORKERS = """
import sys
import ray
from test_shards import _spec
from jaxapf.sweep import read_sweep, run_sweep
from jaxapf.sweep.cluster import RayCluster, RaySession

ray.init(num_cpus=2, num_gpus=2, include_dashboard=False, logging_level="ERROR")  # two GPUs declared, none real
with RaySession(RayCluster(cpus=1, gpus=1)) as session:
    one = session._slots()
with RaySession(RayCluster(cpus=1, gpus=2)) as session:
    two = session._slots()
run_sweep(_spec(), sys.argv[1] + "/ray", chunk_fields=3, quiet=True, ray=RayCluster(cpus=1, gpus=1))
ray.shutdown()
run_sweep(_spec(), sys.argv[1] + "/here", chunk_fields=3, quiet=True)
same = read_sweep(sys.argv[1] + "/ray")[0].equals(read_sweep(sys.argv[1] + "/here")[0])
print(one, two, same)
"""


@pytest.mark.slow
def test_workers_that_each_hold_a_gpu(tmp_path):
    """``--ray --ray-gpus 1`` on a node that declares two GPUs (Ray's resources standing in for real ones):
    two workers, each holding one; one worker when each asks for two; the rows of a one-process run."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "tests" / "sweep"), str(ROOT / "tests")])}
    done = subprocess.run([sys.executable, "-c", _GPU_WORKERS, str(tmp_path)], env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split()[-3:] == ["2", "1", "True"]

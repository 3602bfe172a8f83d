"""Progress in a log: where stderr is not a terminal a long run says how far it is (a line at the first
update, then at most every ``every`` seconds, and at the end), quiet says nothing, a terminal gets the bar."""

from __future__ import annotations

import io
import re

from jaxapf.progress import PROGRESS_LINE, Progress, without_progress


class Log(io.StringIO):
    def __init__(self, tty: bool = False):
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_a_log_gets_a_line_at_the_first_update_then_every_interval_and_at_the_end(monkeypatch):
    clock = iter([0.0, 1.0, 2.0, 40.0, 41.0, 90.0])
    monkeypatch.setattr("jaxapf.progress.time.monotonic", lambda: next(clock))
    log = Log()
    bar = Progress(1000, "sweep", "ep", stream=log)  # t = 0
    bar.update(100)  # t = 1: the first line
    bar.update(100)  # t = 2: within 30 s of it, nothing
    bar.update(300)  # t = 40: a line
    bar.set_postfix(loss="0.25")
    bar.update(500)  # t = 41: within 30 s, nothing
    bar.close()  # t = 90: the end
    lines = log.getvalue().splitlines()
    assert lines == ["sweep: 100/1,000 ep (10 %), 100.0 ep/s, 9.00 s left",
                     "sweep: 500/1,000 ep (50 %), 12.5 ep/s, 40.00 s left",
                     "sweep: 1,000/1,000 ep (100 %), 11.1 ep/s, done in 90.00 s, loss 0.25"]
    assert all(PROGRESS_LINE.match(line) for line in lines)  # what readers of a log tell apart
    assert without_progress(log.getvalue() + "jaxapf sweep: interrupted; 3 part(s) kept") == (
        "jaxapf sweep: interrupted; 3 part(s) kept")


def test_a_resumed_run_counts_its_rate_from_where_it_resumed(monkeypatch):
    clock = iter([0.0, 10.0, 11.0])
    monkeypatch.setattr("jaxapf.progress.time.monotonic", lambda: next(clock))
    log = Log()
    bar = Progress(100, "tune t", "step", stream=log, initial=60)
    bar.update(20)
    bar.close()
    assert log.getvalue().splitlines()[0] == "tune t: 80/100 step (80 %), 2.0 step/s, 10.00 s left"


def test_quiet_says_nothing_and_a_terminal_gets_the_bar():
    log = Log()
    with Progress(10, "x", "ep", quiet=True, stream=log) as bar:
        bar.update(10)
    assert log.getvalue() == ""
    tty = Log(tty=True)
    with Progress(10, "x", "ep", stream=tty) as bar:
        bar.update(10)
    assert re.search(r"x: 100%\|#+\| 10\.0/10\.0", tty.getvalue())  # tqdm's bar, not our lines


def test_a_sweep_logging_to_a_file_says_how_far_it_is(tmp_path, capsys):
    """``run_sweep`` with stderr a file (pytest's capture: not a terminal): the first chunk's line and the
    last one, done/total, rate and time left; quiet, nothing."""
    from jaxapf.sweep import parse_spec, run_sweep

    spec = parse_spec({"name": "logged", "scenario": {"families": ["crossing"], "fields": 4, "seed": 1},
                       "sim": {"t_max": 2.0, "horizon": 4, "iters": 4}, "grid": {"gamma": [0.0, 1.0]}})
    run_sweep(spec, tmp_path / "out.parquet", chunk_fields=2, quiet=False)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("logged: ")]
    assert re.fullmatch(r"logged: 4/8 ep \(50 %\), [\d,.]+ ep/s, .* left", lines[0]), lines
    assert re.fullmatch(r"logged: 8/8 ep \(100 %\), [\d,.]+ ep/s, done in .*", lines[-1]), lines
    run_sweep(spec, tmp_path / "quiet.parquet", chunk_fields=2, quiet=True)
    assert "logged: " not in capsys.readouterr().err

"""The oracle's answers kept on disk (jaxapf.scenarios.answers): asked once per fields and question, read back
only as a bool array of the right shape through the checked opener, never trusted otherwise."""

from __future__ import annotations

import os

import numpy as np
import pytest

import jaxapf.scenarios
from jaxapf.scenarios import answers
from jaxapf.sweep import parse_spec, read_sweep, run_sweep

FIELDS = {"start": np.zeros((3, 3), np.float32), "goal": np.ones((3, 3), np.float32)}
QUESTION = {"r_uav": 0.3, "v_max": 2.0, "t_max": 60.0, "r_goal": 0.5}


def asker(result):
    calls = []

    def ask():
        calls.append(1)
        return np.asarray(result)
    return ask, calls


def test_the_same_question_about_the_same_fields_is_asked_once(tmp_path):
    ask, calls = asker([True, False, True])
    first = answers.remembered(tmp_path, FIELDS, QUESTION, (3,), ask)
    again = answers.remembered(tmp_path, FIELDS, QUESTION, (3,), ask)
    assert calls == [1] and first.tolist() == again.tolist() == [True, False, True] and again.dtype == bool
    other = dict(FIELDS, goal=FIELDS["goal"] + np.float32(1e-6))  # one field moved by a micrometre
    answers.remembered(tmp_path, other, QUESTION, (3,), ask)
    answers.remembered(tmp_path, FIELDS, QUESTION | {"t_max": 30.0}, (3,), ask)
    assert calls == [1, 1, 1]
    answers.remembered(None, FIELDS, QUESTION, (3,), ask)  # no folder: always asked
    assert len(calls) == 4


@pytest.mark.parametrize("planted", ["fifo", "link to /dev/zero", "garbage", "pickle", "wrong shape", "folder"])
def test_a_planted_or_damaged_answer_is_asked_again_without_a_hang(tmp_path, planted):
    name = answers.key(FIELDS, QUESTION)
    path = tmp_path / f"{name}.npy"
    if planted == "fifo":
        os.mkfifo(path)
    elif planted == "link to /dev/zero":
        path.symlink_to("/dev/zero")
    elif planted == "garbage":
        path.write_bytes(b"\x93NUMPY" + os.urandom(200))
    elif planted == "pickle":
        np.save(path, np.array([{"a": 1}] * 3, dtype=object), allow_pickle=True)
    elif planted == "wrong shape":
        np.save(path, np.ones(4, bool))
    else:
        path.mkdir()
    ask, calls = asker([False, True, True])
    assert answers.remembered(tmp_path, FIELDS, QUESTION, (3,), ask).tolist() == [False, True, True]
    assert calls == [1]


def test_a_folder_that_cannot_be_written_only_means_asking_again(tmp_path):
    (tmp_path / "oracle").write_text("a file where the folder would be")
    ask, calls = asker([True, True, True])
    for _ in range(2):
        assert answers.remembered(tmp_path / "oracle", FIELDS, QUESTION, (3,), ask).all()
    assert calls == [1, 1]


SPEC = {"name": "answers", "scenario": {"families": ["trap", "crossing"], "fields": 6, "seed": 3},
        "sim": {"t_max": 1.0, "horizon": 3, "iters": 3}, "grid": {"k_rep": [5.0, 10.0]}}


@pytest.fixture
def counted(monkeypatch):
    """The sweep's oracle, counting the fields it is asked about."""
    asked, real = [], jaxapf.scenarios.solvable

    def solvable(fields, **kwargs):
        asked.append(np.asarray(fields.start).shape[0])
        return real(fields, **kwargs)
    monkeypatch.setattr(jaxapf.scenarios, "solvable", solvable)
    return asked


def test_a_second_sweep_of_the_same_fields_reads_every_answer(tmp_path, counted):
    spec = parse_spec(SPEC)
    run_sweep(spec, tmp_path / "a", chunk_fields=2, quiet=True, answers=tmp_path / "oracle")
    assert sum(counted) == 12  # each field once, whatever the settings
    run_sweep(spec, tmp_path / "b", chunk_fields=3, quiet=True, answers=tmp_path / "oracle")  # other chunks
    assert sum(counted) == 24  # the chunks differ: new questions
    run_sweep(spec, tmp_path / "c", chunk_fields=2, quiet=True, answers=tmp_path / "oracle")
    assert sum(counted) == 24  # the first run's chunks: every answer read
    rows = [read_sweep(tmp_path / o)[0] for o in "abc"]
    assert rows[0]["solvable"].tolist() == rows[2]["solvable"].tolist()
    run_sweep(spec, tmp_path / "d", chunk_fields=2, quiet=True)  # no folder (--no-cache): asked again
    assert sum(counted) == 36


def test_a_resumed_sweep_asks_only_about_the_parts_it_has_still_to_write(tmp_path, counted):
    from jaxapf.validation import Interrupted

    spec = parse_spec(SPEC)

    def stop(chunk):
        raise KeyboardInterrupt
    with pytest.raises(Interrupted):
        run_sweep(spec, tmp_path / "o", chunk_fields=2, quiet=True, after_part=stop)
    first = sum(counted)
    run_sweep(spec, tmp_path / "o", chunk_fields=2, quiet=True)
    assert sum(counted) - first == 12 - 2  # all but the kept part's two fields
    assert read_sweep(tmp_path / "o")[1]["complete"]

"""Animations (jaxapf.simulate.animate): the clip holds the frames its length and rate promise, shows the
UAV moving, and the same file comes from ``jaxapf simulate --animate`` and a report's gallery."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_figures import detour_path, make_field, make_run

from jaxapf.simulate.animate import animate, tracks_of_runs

imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
# the reader forks its ffmpeg with JAX loaded; jaxapf's own encoder says why that is safe (animate._start)
pytestmark = pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")


def _frames(path):
    """The clip's frames below the title (whose clock changes every frame), decoded by imageio-ffmpeg's
    reader (its own ffmpeg child)."""
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    height = meta["size"][1]
    return meta, [np.frombuffer(f, np.uint8).reshape(height, meta["size"][0], 3)[height // 5:] for f in reader]


def test_a_clip_has_the_frames_its_length_promises_and_the_uav_moves(tmp_path):
    field = make_field()
    runs = [make_run("basic", field, detour_path(field))]  # 70 samples of 0.5 s: 34.5 s
    mp4, gif = animate(tracks_of_runs(runs, field), field, tmp_path, fps=10, seconds=3.0)
    assert mp4.name == "episode.mp4" and gif.name == "episode.gif" and gif.stat().st_size > 0
    meta, frames = _frames(mp4)
    # 34.5 s played at 11.5x real time in 3 s: 31 frames at 10 fps, even sides for H.264
    assert len(frames) == 31 and meta["fps"] == 10 and meta["size"][0] % 2 == 0 == meta["size"][1] % 2
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).max() > 100  # something moved
    assert np.array_equal(*[np.asarray(f) for f in (frames[0], _frames(animate(
        tracks_of_runs(runs, field), field, tmp_path / "again", fps=10, seconds=3.0)[0])[1][0])])


def test_moving_obstacles_move_in_the_clip(tmp_path):
    field = make_field()  # obstacle 4 moves at 0.8 m/s in y
    still = make_run("basic", field, np.repeat(field.start[None], 40, axis=0))  # the UAV never moves
    _, frames = _frames(animate(tracks_of_runs([still], field), field, tmp_path, fps=5, seconds=2.0)[0])
    changed = lambda f: int((np.abs(f[0].astype(int) - f[-1].astype(int)).max(axis=-1) > 30).sum())  # noqa: E731
    assert changed(frames) > 300  # the obstacle (a pale sphere's disc) moved
    halted = dataclasses.replace(field, obstacle_velocity=np.zeros_like(field.obstacle_velocity))
    _, frames = _frames(animate(tracks_of_runs([still], halted), halted, tmp_path / "halted", fps=5, seconds=2.0)[0])
    assert changed(frames) < 30  # nothing moves: codec noise only


@pytest.mark.slow
def test_simulate_animate_writes_both_files(tmp_path, capsys):
    from jaxapf.cli import main

    assert main(["simulate", "--family", "circle_swap", "--agents", "4", "--methods", "basic", "--t-max", "6",
                 "--animate", "--out", str(tmp_path)]) == 0
    assert "episode.mp4, episode.gif" in capsys.readouterr().out
    meta, frames = _frames(tmp_path / "episode.mp4")
    assert len(frames) > 10

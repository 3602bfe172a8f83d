"""Episodes you can watch: ``jaxapf simulate --animate`` writes the top view of every method's episode
as a GIF and an MP4, obstacles moving, each UAV (one, or a swarm's) a disc of its radius with a trail.

Frames are drawn once with Matplotlib (Agg, artists moved in place) and encoded by the ffmpeg binary
of ``imageio-ffmpeg`` (the ``video`` extra; no system install): H.264 for the MP4, a palette per clip
for the GIF. Playback compresses time so that a clip lasts at most ``seconds`` (a 60 s episode plays
in 12 s at 5×); the title shows the episode's own clock.
"""

from __future__ import annotations

import dataclasses
import pathlib
import subprocess
from typing import Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from ..io.lock import staged
from ..progress import Progress
from ..validation import ConfigError
from .figures import _GOAL_COLOR, _OBSTACLE_COLOR, DPI, Field, Run, _collision_index, outcome, plain_text

__all__ = ["Track", "tracks_of_runs", "tracks_of_swarm", "animate", "ffmpeg"]

TRAIL_S = 3.0  # a swarm UAV's trail [s]; a single UAV keeps its whole path


@dataclasses.dataclass(frozen=True, eq=False)
class Track:
    """One panel of the clip: a method's UAVs over time.

    Attributes:
      label: the panel's title (method and outcome).
      time: (n,) sample times [s]; position: (A, n, 3); end: (A,) last sample of each UAV; hit: (A,)
      sample of its collision or -1; starts, goals: (A, 3); trail: seconds of path behind each UAV
      (``inf``: all of it).
    """

    label: str
    time: np.ndarray
    position: np.ndarray
    end: np.ndarray
    hit: np.ndarray
    starts: np.ndarray
    goals: np.ndarray
    trail: float


def tracks_of_runs(runs: Sequence[Run], field: Field) -> list[Track]:
    """A panel per single-UAV run, its whole path drawn behind it."""
    out = []
    for r in runs:
        hit = _collision_index(r)
        out.append(Track(f"{r.label}: {outcome(r, field)}", r.time, r.position[None], np.array([len(r.time) - 1]),
                         np.array([-1 if hit is None else hit]), field.start[None], field.goal[None], np.inf))
    return out


def tracks_of_swarm(runs: Sequence, swarm) -> list[Track]:
    """A panel per swarm run (:class:`jaxapf.simulate.swarm.SwarmRun`), every UAV with a short trail."""
    return [Track(f"{r.label}: {r.summary()}", r.time, r.position, r.end, r.hit, swarm.starts, swarm.goals, TRAIL_S)
            for r in runs]


def ffmpeg() -> str:
    """The path of imageio-ffmpeg's ffmpeg; a one-line :class:`ConfigError` naming the extra where it is
    missing (call it before the work whose result is to be animated)."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise ConfigError("--animate needs imageio-ffmpeg: python -m pip install -e \".[video]\"") from None
    return imageio_ffmpeg.get_ffmpeg_exe()


def _legend(field: Field, agents: int, colors: np.ndarray) -> tuple[list, list[str]]:
    """Handles and labels of what every frame draws: start, goal ring, the UAV and its trail, an obstacle
    (where the field has one), a collision."""
    from matplotlib.lines import Line2D

    uav = colors[0] if agents == 1 else "grey"
    handles = [Line2D([], [], marker="s", linestyle="", color="black" if agents == 1 else "grey", markersize=4),
               Line2D([], [], marker="o", linestyle="", markerfacecolor="none",
                      markeredgecolor=_GOAL_COLOR if agents == 1 else "grey", markersize=8),
               Line2D([], [], marker="o", color=uav, markeredgecolor="black", markersize=6, linewidth=1.5),
               Line2D([], [], marker="o", linestyle="", color=_OBSTACLE_COLOR, alpha=0.35, markersize=10),
               Line2D([], [], marker="X", linestyle="", color="red", markeredgecolor="black", markersize=8)]
    labels = ["start", f"goal (within {field.r_goal:g} m)", "UAV and its trail" if agents == 1 else
              "UAVs (one colour each) and trails", "obstacle (where it is now)", "collision"]
    keep = [i for i in range(len(labels)) if i != 3 or field.n_obstacles]  # no obstacle: none in the legend
    return [handles[i] for i in keep], [labels[i] for i in keep]


# long: the panels' artists are built once and moved frame by frame in one loop that feeds both encoders
@plain_text
def animate(tracks: Sequence[Track], field: Field, out: pathlib.Path | str, stem: str = "episode",
            fps: int = 20, seconds: float = 12.0, title: str = "") -> list[pathlib.Path]:
    """Write ``out/stem.mp4`` and ``out/stem.gif`` of ``tracks`` side by side (obstacles of ``field``
    where they are at each instant); returns the two paths."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from .swarm import SwarmField, _bounds, agent_colors

    exe = ffmpeg()
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_end = max(float(t.time[-1]) for t in tracks)
    speed = max(1.0, t_end / seconds)
    frames = max(2, int(round(t_end / speed * fps)) + 1)
    times = np.linspace(0.0, t_end, frames)
    ends = SwarmField(np.concatenate([t.starts for t in tracks]), np.concatenate([t.goals for t in tracks]), field)
    xlim, ylim = _bounds(tracks, ends, [t_end])

    panels = len(tracks)
    aspect = (ylim[1] - ylim[0]) / max(xlim[1] - xlim[0], 1e-9)
    width = min(4.2 * panels, 12.0)
    fig = Figure(figsize=(width, min(width / panels * aspect + 0.9, 9.0)), layout="constrained", dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, panels, squeeze=False, sharex=True, sharey=True)[0]
    agents = max(t.position.shape[0] for t in tracks)
    colors = agent_colors(agents) if agents > 1 else np.array([[0.12, 0.47, 0.71, 1.0]])
    moving = []  # (panel's obstacle patches)
    movers = []  # per panel: (trails, discs, crosses, track)
    for ax, track in zip(axes, tracks):
        patches = []
        for j in range(field.n_obstacles):
            c = Circle(tuple(field.obstacle_position[j, :2]), field.obstacle_radius[j], facecolor=_OBSTACLE_COLOR,
                       edgecolor=_OBSTACLE_COLOR, alpha=0.35 if field.obstacle_cylinder[j] else 0.2, zorder=2)
            ax.add_patch(c)
            patches.append(c)
        moving.append(patches)
        for a in range(track.position.shape[0]):
            ax.add_patch(Circle(tuple(track.goals[a, :2]), field.r_goal, fill=False, zorder=3,
                                edgecolor=colors[a] if agents > 1 else _GOAL_COLOR))
            ax.plot(*track.starts[a, :2], "s", color=colors[a] if agents > 1 else "black", markersize=4, zorder=3)
        trails = [ax.plot([], [], "-", color=colors[a], linewidth=1.5, zorder=4)[0]
                  for a in range(track.position.shape[0])]
        discs = [ax.add_patch(Circle((np.nan, np.nan), field.r_uav, facecolor=colors[a], edgecolor="black",
                                     linewidth=0.6, zorder=5)) for a in range(track.position.shape[0])]
        cross = ax.plot([], [], "X", color="red", markeredgecolor="black", markersize=10, zorder=6)[0]
        movers.append((trails, discs, cross, track))
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(track.label, fontsize=9)
        ax.set_xlabel("x [m]")
        ax.grid(True, linewidth=0.4, alpha=0.5)
    axes[0].set_ylabel("y [m]")
    heading = fig.suptitle("", fontsize=10)
    fig.legend(*_legend(field, agents, colors), loc="outside lower center", ncols=5, fontsize=7, frameon=False)

    fig.canvas.draw()
    fig.set_layout_engine("none")  # laid out once: the changing heading must not move the panels or the legend
    size = fig.canvas.get_width_height()
    even = (size[0] - size[0] % 2, size[1] - size[1] % 2)  # H.264 in yuv420p wants even sides
    mp4 = out / f"{stem}.mp4"
    gif = out / f"{stem}.gif"
    # ffmpeg writes hidden files created anew, renamed into place: never through a name planted in ``out``
    with staged(mp4, durable=False) as tmp_mp4, staged(gif, durable=False) as tmp_gif:
        cmd = [exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgba", "-s", f"{size[0]}x{size[1]}",
               "-r", str(fps), "-i", "-", "-vf", f"crop={even[0]}:{even[1]}:0:0", "-c:v", "libx264", "-pix_fmt",
               "yuv420p", "-movflags", "+faststart", "-f", "mp4", str(tmp_mp4)]
        with _start(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE) as encoder, \
                Progress(frames, f"animate {stem}", "frame", every=2.0) as bar:
            try:
                for t in times:
                    for patches in moving:
                        centres = field.obstacles_at(t)
                        for j, c in enumerate(patches):
                            c.center = tuple(centres[j, :2])
                    for trails, discs, cross, track in movers:
                        k = int(np.searchsorted(track.time, t, side="right")) - 1
                        for a in range(track.position.shape[0]):
                            i = min(k, int(track.end[a]))
                            first = (0 if not np.isfinite(track.trail)
                                     else int(np.searchsorted(track.time, t - track.trail)))
                            p = track.position[a, min(first, i): i + 1]
                            trails[a].set_data(p[:, 0], p[:, 1])
                            discs[a].center = tuple(track.position[a, i, :2])
                        hits = [track.position[a, h, :2] for a, h in enumerate(track.hit) if 0 <= h <= k]
                        cross.set_data([h[0] for h in hits], [h[1] for h in hits])
                    heading.set_text(f"{title + ' — ' if title else ''}t = {t:5.1f} s ({speed:.3g}× real time)")
                    fig.canvas.draw()
                    encoder.stdin.write(bytes(fig.canvas.buffer_rgba()))
                    bar.update(1)
                encoder.stdin.close()
            except BrokenPipeError:  # ffmpeg ended early: its message says why
                pass
            except BaseException:
                encoder.kill()
                raise
            error = encoder.stderr.read().decode(errors="replace").strip()
            if encoder.wait() != 0:
                raise ConfigError(f"ffmpeg could not write {mp4}: {error.splitlines()[-1] if error else 'no message'}")
        palette = (f"fps={min(fps, 12)},scale={min(even[0], 800)}:-1:flags=lanczos,split[a][b];"
                   "[a]palettegen=max_colors=128[p];[b][p]paletteuse=dither=bayer")
        with _start([exe, "-y", "-loglevel", "error", "-f", "mp4", "-i", str(tmp_mp4), "-vf", palette,
                    "-f", "gif", str(tmp_gif)],
                    stderr=subprocess.PIPE, text=True) as done:
            error = done.communicate()[1].strip()
        if done.returncode != 0:
            raise ConfigError(f"ffmpeg could not write {gif}: {error.splitlines()[-1] if error else 'no message'}")
    return [mp4, gif]


def _start(cmd: list[str], **kw) -> subprocess.Popen:
    """ffmpeg in a child process. JAX warns of any fork in a process that runs it; this child execs at once
    (``_posixsubprocess``: no Python runs between fork and exec), so no lock JAX holds can be inherited."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
        return subprocess.Popen(cmd, **kw)

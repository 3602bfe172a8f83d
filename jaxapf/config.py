"""Static configuration: what is compiled into a program (changing it recompiles).

Every class here is frozen and hashable and is passed to ``jit`` as a static argument. Numbers
that vary across a grid of settings are gains (:mod:`jaxapf.gains`), not configuration.

:class:`SimConfig` gathers five concerns, each its own class:

==================  ===========================================================================
:class:`PlannerConfig`  which planner (``method``) and safety filter, and the potential's settings
:class:`VehicleConfig`  which plant, its limits and size
:class:`WorldConfig`    what stands between the world and the stack: sensing model, disturbance
:class:`EpisodeConfig`  time step, episode length, goal tolerance
:class:`MetricConfig`   thresholds of the metrics (stall, near miss)
==================  ===========================================================================

Sweep specs and the CLI address every field by its own name in one flat namespace (``method``,
``dt``, ``a_max``, ...: :data:`SIM_KEYS`), which :meth:`SimConfig.from_flat` routes to its part.
:class:`MPCConfig` is the tracking controller's configuration (paper eq. 8–12).

Constructors validate before anything is traced and raise
:class:`~jaxapf.validation.ConfigError` naming the field and its allowed range. Names of planners,
filters and plants are checked against their registries when a program is built (and by every
spec parser), not here, so this module depends on no component.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal, Mapping

import numpy as np

from .validation import ConfigError, check_choice, check_int, check_range

__all__ = [
    "CONVENTIONS",
    "PlannerConfig",
    "VehicleConfig",
    "WorldConfig",
    "VELOCITY_ESTIMATES",
    "EpisodeConfig",
    "MetricConfig",
    "SimConfig",
    "MPCConfig",
    "SIM_KEYS",
    "MPC_KEYS",
    "STATIC_KEYS",
]

#: Sign conventions of the direction and velocity weights (SPEC 3).
CONVENTIONS = ("intent", "literal")

Convention = Literal["intent", "literal"]


def _positive(owner: Any, names: tuple[str, ...], prefix: str) -> None:
    for name in names:
        object.__setattr__(owner, name, float(check_range(f"{prefix}.{name}", getattr(owner, name), 0.0, lo_open=True)))


def _nonnegative(owner: Any, names: tuple[str, ...], prefix: str) -> None:
    for name in names:
        object.__setattr__(owner, name, float(check_range(f"{prefix}.{name}", getattr(owner, name), 0.0)))


def _name(where: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where} = {value!r} must be a name")
    return value


#: Where the MPC's weights come from (:attr:`PlannerConfig.mpc_weights`).
MPC_WEIGHTS: tuple[str, ...] = ("static", "gains")
#: How the planner's reference is followed (:attr:`PlannerConfig.tracking`).
TRACKING: tuple[str, ...] = ("mpc", "ideal")


@dataclasses.dataclass(frozen=True)
class PlannerConfig:
    r"""The avoidance stack: planner, safety filter, disturbance estimator and the potentials' settings (SPEC 3–4).

    Attributes:
      method: planner, a name of :data:`jaxapf.planners.PLANNERS` (``basic``, ``direction``,
        ``direction_velocity``, ...).
      filter: safety filter between the MPC and the plant, a name of
        :data:`jaxapf.control.FILTERS` (``none``: the MPC's acceleration is applied as it is).
      estimator: disturbance estimator for offset-free tracking, a name of
        :data:`jaxapf.control.ESTIMATORS` (``none``: the MPC plans without a disturbance).
      convention: ``intent`` (default, the paper's prose) | ``literal`` (its printed formulas), SPEC 3.
      d_min: floor [m] > 0 on the clearance inside the repulsive potential (no inf/NaN).
      eps_v: regulariser [m/s] > 0 of |v| in cos θ: a hovering UAV has cos θ = 0.
      att_cap: distance [m] beyond which the attractive potential turns conic (linear in
        distance); ``None`` (default) keeps it quadratic everywhere.
      reference_velocity: use the flow velocities u_i as the MPC velocity reference instead of
        the paper's zero (off by default).
      mpc_weights: ``static`` (default): the MPC's weights of :class:`MPCConfig`, compiled in (its
        matrices built once for every episode); ``gains``: those weights times the traced scale gains
        ``mpc_pos``, ``mpc_vel``, ``mpc_terminal``, ``mpc_input``, ``mpc_speed`` (matrices built per
        episode, so a grid over them is one vmap and ``jaxapf tune`` differentiates through them).
      projection_rows: the exact projections (the CBF filter's, the velocity obstacles') solve with
        ``projection_rows`` obstacle rows at a time (0, default: all), ``O(rows⁴)`` work instead of
        ``O(M⁴)``: first those that can bind soonest in the box or ball, then, while a row left out is
        violated at the answer, the rows active there and the most violated (up to 8 solves, then one
        with twice the rows); the steps still not certified exact are counted (``cbf_truncated_steps``,
        ``vo_truncated_steps``; :func:`jaxapf.projection.nearest_feasible`).
      tracking: ``mpc`` (default): the box-constrained MPC tracks the planner's reference; ``ideal``: an
        ablation without it, the reference's first velocity ``(p_1 - p) / Δt`` (a velocity obstacle's
        chosen velocity) reached within the step, whatever the acceleration it takes (no box; a safety
        filter still keeps its own); no disturbance estimator. A planner that flies its own plan
        (``mppi``, ``keepout_mpc``: :meth:`jaxapf.planners.Planner.command`) is tracked by neither.
      mppi_samples: the sampled acceleration sequences ``K`` of the ``mppi`` planner per control step
        (:mod:`jaxapf.planners.mppi`; static: it sets the shape of its batch).
    """

    method: str = "direction_velocity"
    filter: str = "none"
    estimator: str = "none"
    convention: Convention = "intent"
    d_min: float = 0.05
    eps_v: float = 1e-3
    att_cap: float | None = None
    reference_velocity: bool = False
    mpc_weights: str = "static"
    projection_rows: int = 0
    tracking: str = "mpc"
    mppi_samples: int = 256

    def __post_init__(self) -> None:
        _name("sim.method", self.method)
        _name("sim.filter", self.filter)
        _name("sim.estimator", self.estimator)
        check_choice("sim.convention", self.convention, CONVENTIONS)
        _positive(self, ("d_min", "eps_v"), "sim")
        if self.att_cap is not None:
            object.__setattr__(self, "att_cap", float(check_range("sim.att_cap", self.att_cap, 0.0, lo_open=True)))
        if not isinstance(self.reference_velocity, (bool, np.bool_)):
            raise ConfigError(f"sim.reference_velocity = {self.reference_velocity!r} must be true or false")
        check_choice("sim.mpc_weights", self.mpc_weights, MPC_WEIGHTS)
        check_int("sim.projection_rows", self.projection_rows, 0, 1000)
        check_choice("sim.tracking", self.tracking, TRACKING)
        check_int("sim.mppi_samples", self.mppi_samples, 1, 65536)
        if self.tracking == "ideal" and self.estimator != "none":
            raise ConfigError(f"sim.tracking = 'ideal' flies without the MPC: sim.estimator must be 'none', "
                              f"not {self.estimator!r}")


#: The Crazyflie airframes ``drone-models`` identifies (:mod:`jaxapf.world.crazyflie`).
AIRFRAMES = ("cf2x_L250", "cf2x_P250", "cf2x_T350", "cf21B_500")


@dataclasses.dataclass(frozen=True)
class VehicleConfig:
    """The vehicle: plant model, limits and size (SPEC 1).

    Attributes:
      plant: a name of :data:`jaxapf.world.PLANTS` (``double_integrator``: the MPC's own model).
      a_max: per-axis acceleration limit [m/s²] > 0 (hard box of the MPC).
      v_max: per-axis velocity limit [m/s] > 0 (MPC penalty; also the norm cap of the reference).
      r_uav: UAV sphere radius [m] >= 0.
      substeps: inner integration steps per control step of a plant with an inner loop (the
        quadrotor's attitude controller and rigid body run at ``substeps / dt``); the double
        integrator, exact, ignores it.
      airframe: the Crazyflie the ``crazyflie_*`` plants fly (:data:`AIRFRAMES`, ``drone-models``'
        identified configurations); other plants ignore it.
    """

    plant: str = "double_integrator"
    a_max: float = 3.0
    v_max: float = 2.0
    r_uav: float = 0.3
    substeps: int = 10
    airframe: str = "cf2x_L250"

    def __post_init__(self) -> None:
        _name("sim.plant", self.plant)
        _positive(self, ("a_max", "v_max"), "sim")
        _nonnegative(self, ("r_uav",), "sim")
        check_int("sim.substeps", self.substeps, 1, 10_000)
        check_choice("sim.airframe", self.airframe, AIRFRAMES)


#: How the noisy sensor estimates an obstacle's velocity (:mod:`jaxapf.world.sensing`).
VELOCITY_ESTIMATES = ("measured", "differenced")


@dataclasses.dataclass(frozen=True)
class WorldConfig:
    """What stands between the world and the avoidance stack (:mod:`jaxapf.world.sensing`,
    :mod:`jaxapf.world.wind`); the plant and the metrics always see the truth.

    Attributes:
      sensor: how the planner, MPC and filter see the UAV and the obstacles, a name of
        :data:`jaxapf.world.sensing.SENSORS` (``ideal``: the truth, instantly; ``noisy``: noise, range,
        latency and dropout, each set by a traced gain).
      disturbance: what acts on the plant besides the command, a name of
        :data:`jaxapf.world.DISTURBANCES` (``none``; ``wind``: a constant wind with
        Ornstein-Uhlenbeck gusts).
      velocity_estimate: the noisy sensor's obstacle velocity: ``measured`` (truth plus noise of
        ``sigma_obs_v``) or ``differenced`` (finite difference of two consecutive noisy positions).
      max_latency: the largest latency [control steps] the noisy sensor can apply (the length of its
        history; the gain ``latency`` is clipped to it).
      max_neighbours: in a swarm, the other UAVs each UAV's stack sees: the ``max_neighbours`` nearest
        (RVO2's ``maxNeighbors``), or every other one with 0 (default). Bounds the obstacle slots of each
        UAV's planner and filter to ``M + max_neighbours`` (:mod:`jaxapf.datatypes.swarm`).
    """

    sensor: str = "ideal"
    disturbance: str = "none"
    velocity_estimate: Literal["measured", "differenced"] = "measured"
    max_latency: int = 10
    max_neighbours: int = 0

    def __post_init__(self) -> None:
        _name("sim.sensor", self.sensor)
        _name("sim.disturbance", self.disturbance)
        check_choice("sim.velocity_estimate", self.velocity_estimate, VELOCITY_ESTIMATES)
        check_int("sim.max_latency", self.max_latency, 0, 1000)
        check_int("sim.max_neighbours", self.max_neighbours, 0, 1000)


@dataclasses.dataclass(frozen=True)
class EpisodeConfig:
    """Time and termination of an episode.

    Attributes:
      dt: control / integration step [s] > 0.
      t_max: episode length [s] > 0 (``steps = round(t_max / dt)``).
      r_goal: goal tolerance [m] > 0.
    """

    dt: float = 0.1
    t_max: float = 60.0
    r_goal: float = 0.5

    def __post_init__(self) -> None:
        _positive(self, ("dt", "t_max", "r_goal"), "sim")
        if self.t_max / self.dt < 1:
            raise ConfigError(f"sim.t_max = {self.t_max!r} must be at least one step (sim.dt = {self.dt!r})")
        check_int("sim.steps", self.steps, 1, 10_000_000)

    @property
    def steps(self) -> int:
        """Number of control steps T of an episode."""
        return int(round(self.t_max / self.dt))


@dataclasses.dataclass(frozen=True)
class MetricConfig:
    """Thresholds of the metrics (SPEC 6).

    Attributes:
      v_stall, t_stall, d_progress: stall = speed below ``v_stall`` [m/s] for at least ``t_stall``
        [s] while farther than ``r_goal`` from the goal, getting less than ``d_progress`` [m] closer
        to it over that time (a slow final approach that still closes in is not a stall).
      d_safe: clearance [m] below which time counts as ``time_near``.
      d_sense: clearance [m] within which an obstacle the sensor did not detect counts in
        ``unseen_steps`` (default the paper's influence distance ``d_s``, 4 m).
    """

    v_stall: float = 0.1
    t_stall: float = 3.0
    d_progress: float = 0.1
    d_safe: float = 1.0
    d_sense: float = 4.0

    def __post_init__(self) -> None:
        _positive(self, ("v_stall", "t_stall"), "sim")
        _nonnegative(self, ("d_progress", "d_safe", "d_sense"), "sim")


_PARTS: Mapping[str, type] = {"planner": PlannerConfig, "vehicle": VehicleConfig, "world": WorldConfig,
                              "episode": EpisodeConfig, "metrics": MetricConfig}
#: Every field of the five parts by its flat name (sweep specs, ``[sim]`` tables, CLI).
SIM_KEYS: tuple[str, ...] = tuple(f.name for cls in _PARTS.values() for f in dataclasses.fields(cls))
_OWNER: Mapping[str, str] = {f.name: part for part, cls in _PARTS.items() for f in dataclasses.fields(cls)}


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Everything static about an episode but the MPC: five parts by concern (module docstring).

    ``SimConfig.from_flat(method="basic", t_max=30.0)`` builds one from flat names;
    :meth:`flat` and :meth:`replace` work with flat names too.
    """

    planner: PlannerConfig = PlannerConfig()
    vehicle: VehicleConfig = VehicleConfig()
    world: WorldConfig = WorldConfig()
    episode: EpisodeConfig = EpisodeConfig()
    metrics: MetricConfig = MetricConfig()

    def __post_init__(self) -> None:
        for part, cls in _PARTS.items():
            if not isinstance(getattr(self, part), cls):
                raise ConfigError(f"SimConfig.{part} must be a {cls.__name__}, got {getattr(self, part)!r}")

    @classmethod
    def from_flat(cls, values: Mapping[str, Any] | None = None, /, **kwargs: Any) -> "SimConfig":
        """A config from flat field names (``method``, ``dt``, ...); unknown names raise
        :class:`ConfigError` listing :data:`SIM_KEYS`."""
        values = {**(values or {}), **kwargs}
        for key in values:
            if key not in _OWNER:
                raise ConfigError(f"sim.{key} is not a simulation setting; allowed: {', '.join(SIM_KEYS)}")
        return cls(**{part: c(**{k: v for k, v in values.items() if _OWNER[k] == part}) for part, c in _PARTS.items()})

    def flat(self) -> dict[str, Any]:
        """Every field by its flat name."""
        return {k: getattr(getattr(self, _OWNER[k]), k) for k in SIM_KEYS}

    def replace(self, **changes: Any) -> "SimConfig":
        """The same config with fields changed by flat name."""
        return SimConfig.from_flat(self.flat() | changes)


def _axis_weight(where: str, value: Any) -> tuple[float, float, float]:
    """A per-axis weight: a number (same on x, y, z) or a 3-sequence, each >= 0."""
    arr = check_range(where, value, 0.0)
    if arr.ndim == 0:
        arr = np.repeat(arr, 3)
    if arr.shape != (3,):
        raise ConfigError(f"{where} must be a number or 3 numbers (x, y, z); got shape {arr.shape}")
    return tuple(float(a) for a in arr)


@dataclasses.dataclass(frozen=True)
class MPCConfig:
    r"""Box-constrained condensed MPC (paper eq. 8–12, SPEC 4).

    Attributes:
      horizon: prediction horizon N >= 1 (also the number of APF prediction points).
      iters: fixed FISTA iteration count >= 1.
      q_pos, q_vel: stage weights on predicted position / velocity, per axis (number or 3-tuple).
      f_pos, f_vel: terminal weights on x(k+N), per axis.
      r: input weight on every acceleration, per axis (> 0 keeps H positive definite).
      v_penalty: weight ρ >= 0 of the smooth convex penalty ½ρ Σ max(|v_i| - v_max, 0)² on the
        predicted velocities (the paper's velocity limit, kept inside the box-QP loop).
    """

    horizon: int = 20
    iters: int = 30
    q_pos: Any = 1.0
    q_vel: Any = 0.05
    f_pos: Any = 5.0
    f_vel: Any = 0.5
    r: Any = 0.05
    v_penalty: float = 10.0

    def __post_init__(self) -> None:
        check_int("mpc.horizon", self.horizon, 1, 500)
        check_int("mpc.iters", self.iters, 1, 10_000)
        for name in ("q_pos", "q_vel", "f_pos", "f_vel"):
            object.__setattr__(self, name, _axis_weight(f"mpc.{name}", getattr(self, name)))
        r = _axis_weight("mpc.r", self.r)
        if min(r) <= 0:
            raise ConfigError(f"mpc.r = {min(r)!r} is out of range; allowed: a finite number > 0")
        object.__setattr__(self, "r", r)
        object.__setattr__(self, "v_penalty", float(check_range("mpc.v_penalty", self.v_penalty, 0.0)))


MPC_KEYS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(MPCConfig))
#: Every static setting of a sweep spec: simulation settings, then MPC settings.
STATIC_KEYS: tuple[str, ...] = SIM_KEYS + MPC_KEYS

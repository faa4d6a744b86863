"""Environment configuration: typed sections, YAML loading, presets and validation.

A config is a frozen tree of dataclasses. YAML files map onto it section by section; unknown keys,
wrong types and invalid values raise ``ValueError`` naming the key and listing the valid options,
before anything is compiled. The defaults reproduce the original's shipped flat configuration
(``flat_config.yaml``: hsaTerrainNoStiffModel, frame_skip 20, weights below), with the original's
quirks fixed as listed in ``docs/environment.md``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from hsa_mjx import migrations
from hsa_mjx.config_schema import build_section, non_finite, plain
from hsa_mjx.randomization_config import NOMINAL, ObservationNoiseConfig, RandomizationConfig
from hsa_mjx.randomization_config import validate as validate_randomization
from hsa_mjx.resources import data_dir, merge, read_yaml
from hsa_mjx.robots import DEFAULT as DEFAULT_ROBOT
from hsa_mjx.robots import drawn_servos, robot_env
from hsa_mjx.servo_config import ServoConfig, resolve_servo
from hsa_mjx.servo_config import validate as validate_servo
from hsa_mjx.terrain.height_scan import HeightScanConfig
from hsa_mjx.terrain.height_scan import validate as validate_height_scan
from hsa_mjx.terrain.params import TERRAIN_TYPES as GENERATOR_TYPES
from hsa_mjx.terrain.params import TerrainConfig, validate_terrain, with_default_proportions

SCENES = ("flat", "terrain")
BACKENDS = ("auto", "jax", "warp", "c")  # physics.backend (hsa_mjx.sim.backend): c = C MuJoCo substeps
INTEGRATORS = ("euler", "implicitfast", "rk4")
SOLVERS = ("newton", "cg")
CONES = ("pyramidal", "elliptic")
GOAL_MODES = ("fixed", "random", "radial", "spiral")
HINGE_ANGLE_MODES = ("raw", "wrapped", "sincos")  # observation.hinge_angles
VELOCITY_MODES = ("simulated", "differenced")  # observation.velocity
PROGRESS_MODES = ("euclidean", "geodesic")  # reward.progress
MAX_HISTORY = 16  # observation.history_steps: a short history, not a sequence model
MIXED = migrations.MIXED  # terrain_type of a batch drawing from several types (terrain.types)
TERRAIN_TYPES = GENERATOR_TYPES + (MIXED,)


@dataclasses.dataclass(frozen=True)
class PhysicsConfig:
    """Simulator settings written into the MuJoCo model at load time."""

    timestep: float = 0.001
    integrator: str = "euler"
    solver: str = "newton"
    iterations: int = 100
    ls_iterations: int = 50
    tolerance: float = 1e-8
    cone: str = "pyramidal"
    # MJX implementation: "jax", "warp" (MuJoCo Warp, needs warp-lang) or "auto" (warp on a CUDA GPU
    # when warp-lang imports, else jax). Results record the one used.
    backend: str = "auto"
    # Warp only: each env's share of the contact buffer all envs of a batch share, and its constraint
    # rows (the JAX implementation allocates every candidate contact statically and ignores both).
    contacts_per_env: int = 48
    constraints_per_env: int = 192


@dataclasses.dataclass(frozen=True)
class ControlConfig:
    """Incremental position control of the eight servos."""

    frame_skip: int = 20
    max_increment: float = 0.1785
    smooth_positions: bool = True
    servo_target_limit: float = 3141.5  # hsaTerrainNoStiffModel ctrlrange; hsaLooseModel uses 6.28


@dataclasses.dataclass(frozen=True)
class RewardConfig:
    """Weights and constants of every reward term: each weight has its term's name (the logged
    ``episode/reward/<name>``); older configs' short names (``ctrl``, ``lateral``, ...) are mapped by
    ``hsa_mjx.migrations``."""

    forward: float = 6.0
    forward_rectified: bool = False  # original: max(0, v.u); rewards back-and-forth oscillation
    lateral_cost: float = 0.0  # subtracted as a cost (the original added it)
    ctrl_cost: float = 0.001
    contact_cost: float = 0.0005
    contact_force_threshold: float = 50.0
    constraint_cost: float = 0.05
    constraint_margin: float = 0.01
    constraint_bonus: float = 0.025
    acceleration_cost: float = 1e-5
    joint_velocity_cost: float = 5e-4
    distance: float = 10.0
    stagnation_cost: float = 0.15  # flat_config lacked the key; the class default applied
    stagnation_window: int = 50
    stagnation_threshold: float = 0.05
    alive: float = 0.03
    goal_bonus: float = 40.0
    checkpoint: float = 200.0
    spiral_completion: float = 100.0
    termination: float = 100.0  # the original hard-coded 100 whatever the config said
    # Not in the original (0 keeps its reward): potential-style shaping that pays turning the robot's
    # axis towards the goal, w * (|cos| after - |cos| before) of the axis-to-goal angle per step.
    heading_alignment: float = 0.0
    # Caps (largest cost per step) and clips (largest value a term reads) of the cost terms: the
    # original's constants. Like the weights, traced per env.
    velocity_clip: float = 5.0  # m/s, each component of the robot velocity forward and lateral_cost read
    ctrl_cost_cap: float = 20.0
    contact_cost_cap: float = 30.0
    constraint_cost_cap: float = 50.0
    acceleration_clip: float = 50.0  # rad/s^2, each hinge
    acceleration_cost_cap: float = 20.0
    joint_velocity_clip: float = 50.0  # rad/s, each hinge
    joint_velocity_cost_cap: float = 50.0
    # How the distance and forward terms (and the logged distance_to_goal) measure the way to the goal:
    # euclidean (the original: the straight line) or geodesic (along the ground the robot can cross, from
    # the distance fields of the terrain's goal sites: terrain.reachability; hsa_mjx.terrain.geodesic).
    progress: str = "euclidean"


@dataclasses.dataclass(frozen=True)
class TerminationConfig:
    """Limits that end an episode early, and the episode length that truncates it."""

    max_episode_steps: int = 4000
    z_min: float = -0.5
    z_max: float = 0.5
    qvel_limit: float = 2000.0
    qacc_limit: float = 15000.0
    # |qacc| is checked at the last substep of an env step, as the original did; true checks every
    # substep (also catches transient impacts of the light hinges, which are not blow-ups: qvel and
    # finiteness are always checked at every substep). See docs/training.md.
    qacc_every_substep: bool = False
    # false: no joint-acceleration rule (the original's, a simulator-health check that stiffer springs
    # trip on a sound gait); episodes then end on non-finite states, block heights, qvel_limit, leaving
    # the arena and the goal. benchmarks.robustness.score scores that way by default (docs/robustness.md).
    qacc_termination: bool = True


@dataclasses.dataclass(frozen=True)
class GoalConfig:
    """How each env's goal is chosen at reset and when it counts as reached."""

    mode: str = "random"  # fixed | random (original rules) | radial (curriculum range) | spiral
    position: tuple[float, float] = (1.5, 0.0)  # fixed mode
    success_radius: float = 0.2
    radial_range: tuple[float, float] = (1.5, 1.8)  # radial mode: distance range of new goals
    # radial mode: |angle| of the goal direction from world +x (the robot spawns facing +x), in
    # degrees, either side; (0, 180) = any direction, (60, 120) = beside the robot (a turning task)
    radial_bearing_deg: tuple[float, float] = (0.0, 180.0)
    num_checkpoints: int = 8
    checkpoint_radius: float = 0.4  # spiral mode: the checkpoints lie on terrain.spiral's path
    # spiral mode, a training aid: > 0 starts each episode at checkpoint k, k uniform in
    # 0..track_starts (k > 0: on checkpoint k - 1, facing checkpoint k), so that training sees the
    # whole track, not only its start. 0 = the original (always the origin); evaluation uses 0.
    track_starts: int = 0


@dataclasses.dataclass(frozen=True)
class ObservationConfig:
    """Optional observation entries beyond the original's 24 values."""

    # true appends the heading (cos, sin of yaw, block A -> block B) and the unit vector to the
    # goal in that heading frame: 28 values. Off keeps the original's 24 (no orientation at all).
    heading: bool = False
    # true appends the 8 servo targets (rad, action-slot order): the actions are increments of
    # them, so without them the policy's own control state is hidden (the original's obs lacks it).
    servo_targets: bool = False
    # > 0 appends a gait clock, (sin, cos) of 2 pi t / clock_period_s with t the episode time:
    # a phase signal from which a periodic gait is a plain function of the observation. 0 = off.
    clock_period_s: float = 0.0
    # true appends the way the path to the goal leaves the robot (the geodesic field's downhill unit
    # vector, hsa_mjx.task.progress) in the heading frame (ahead, left): 2 values. Needs
    # reward.progress 'geodesic'; the straight goal direction where the goal has no site.
    path_direction: bool = False
    # How the 8 actuated hinge angles enter: "raw" (the original: unbounded, they wind up over long
    # episodes), "wrapped" (into [-pi, pi): same size) or "sincos" (sin then cos: 8 more values).
    hinge_angles: str = "raw"
    # terrain heights on a grid around the robot, turned with its heading (hsa_mjx.terrain.height_scan): appended last
    height_scan: HeightScanConfig = HeightScanConfig()
    # uniform noise per observation group on the policy's copy (hsa_mjx.randomization_config)
    noise: ObservationNoiseConfig = ObservationNoiseConfig()
    # The robot's velocity entries: "simulated" (the blocks' mean velocity, exact, plus the velocity
    # noise) or "differenced" (as a robot measures it: a position tracker, noise.position of jitter on
    # each reading, differenced over one control step; the position entries are the tracker's too)
    velocity: str = "simulated"
    # > 0 appends the last history_steps observations (without scan) and actions, newest first
    # (hsa_mjx.task.history): what the policy needs to identify a model it cannot see. 0 = off.
    history_steps: int = 0


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Everything that defines one HSA environment."""

    name: str = "flat"
    # the robot profile (hsa_mjx.robots, a shipped name or a file): the servo, control rate, sensors and
    # latency a builder chose; keys given beside it win over it
    robot: str = DEFAULT_ROBOT
    scene: str = "flat"
    spawn_height: float = 0.2
    physics: PhysicsConfig = PhysicsConfig()
    control: ControlConfig = ControlConfig()
    reward: RewardConfig = RewardConfig()
    termination: TerminationConfig = TerminationConfig()
    goal: GoalConfig = GoalConfig()
    terrain: TerrainConfig = TerrainConfig()
    observation: ObservationConfig = ObservationConfig()
    randomization: RandomizationConfig = RandomizationConfig()
    servo: ServoConfig = ServoConfig()  # the servo model (hsa_mjx.sim.servo): the asset's springs by default

    def __post_init__(self) -> None:
        validate(self)  # every config is valid from the moment it is built: no later check repeats it

    @property
    def terrain_type(self) -> str:
        """The terrain's one type, or ``mixed`` for several (``terrain.types``; the key is a shorthand)."""
        types = self.terrain.types
        return types[0] if len(types) == 1 else MIXED

    @property
    def dt(self) -> float:
        """Length of one environment step in seconds."""
        return self.physics.timestep * self.control.frame_skip


_CHOICES = {
    ("scene",): SCENES,
    ("physics", "integrator"): INTEGRATORS,
    ("physics", "solver"): SOLVERS,
    ("physics", "cone"): CONES,
    ("physics", "backend"): BACKENDS,
    ("goal", "mode"): GOAL_MODES,
    ("observation", "hinge_angles"): HINGE_ANGLE_MODES,
    ("observation", "velocity"): VELOCITY_MODES,
    ("reward", "progress"): PROGRESS_MODES,
}
_POSITIVE = {
    ("physics", "timestep"),
    ("physics", "iterations"),
    ("physics", "ls_iterations"),
    ("physics", "contacts_per_env"),
    ("physics", "constraints_per_env"),
    ("control", "frame_skip"),
    ("control", "servo_target_limit"),
    ("termination", "max_episode_steps"),
    ("termination", "qvel_limit"),
    ("termination", "qacc_limit"),
    ("goal", "success_radius"),
    ("goal", "num_checkpoints"),
    ("goal", "checkpoint_radius"),
    ("reward", "stagnation_window"),
}


def validate(config: EnvConfig) -> EnvConfig:
    """Check choices and value ranges; return the config unchanged or raise ValueError."""
    bad = non_finite(config)
    if bad:
        raise ValueError(f"config values must be finite numbers; got {bad}")
    for path, choices in _CHOICES.items():
        value = _get(config, path)
        if value not in choices:
            raise ValueError(f"config key '{'.'.join(path)}' = {value!r} is not valid; choose one of {list(choices)}")
    for path in _POSITIVE:
        if not _get(config, path) > 0:
            raise ValueError(f"config key '{'.'.join(path)}' must be > 0, got {_get(config, path)!r}")
    lo, hi = config.goal.radial_range
    if not 0 <= lo <= hi:
        raise ValueError(f"config key 'goal.radial_range' must satisfy 0 <= min <= max, got {(lo, hi)}")
    lo, hi = config.goal.radial_bearing_deg
    if not 0 <= lo <= hi <= 180:
        raise ValueError(
            "config key 'goal.radial_bearing_deg' must satisfy 0 <= min <= max <= 180 "
            f"(degrees from +x, either side), got {(lo, hi)}"
        )
    if config.termination.z_min >= config.termination.z_max:
        raise ValueError("config keys 'termination.z_min' must be below 'termination.z_max'")
    if config.physics.tolerance < 0:
        raise ValueError("config key 'physics.tolerance' must be >= 0")
    if config.observation.clock_period_s < 0:
        raise ValueError(
            "config key 'observation.clock_period_s' must be >= 0 (0 turns the gait clock off), "
            f"got {config.observation.clock_period_s!r}"
        )
    if not 0 <= config.observation.history_steps <= MAX_HISTORY:
        raise ValueError(
            f"config key 'observation.history_steps' must be an integer in 0..{MAX_HISTORY} (0 turns the "
            f"history off), got {config.observation.history_steps!r}"
        )
    validate_height_scan(config.observation.height_scan)
    validate_randomization(config.randomization, config.observation.noise)
    _validate_servo(config)
    _validate_track_starts(config.goal)
    _validate_terrain(config)
    return config


def _validate_servo(config: EnvConfig) -> None:
    """The servo section; the randomised servo gain and torque limit act on the asset's springs only,
    the drawn robots and servo figures on DC-motor servos only."""
    validate_servo(config.servo)
    rand = config.randomization
    dc_motors = resolve_servo(config.servo) is not None
    if (rand.robots or rand.servo_figures != NOMINAL) and not dc_motors:
        raise ValueError(
            "config keys 'randomization.robots' and 'randomization.servo_figures' draw DC-motor servos: set "
            "env.robot to a profile with one (or servo.model position or continuous)"
        )
    drawn = drawn_servos(rand.robots)  # each a profile with a DC-motor servo
    if any(p.friction > 0 for p in drawn) and not config.servo.friction > 0:
        raise ValueError(
            "config key 'randomization.robots' draws servos with friction: the env's own servo needs "
            "servo.friction > 0 too (MJX builds friction rows only for joints whose model has friction)"
        )
    if dc_motors and (rand.limits_force or rand.servo_gain != NOMINAL):
        raise ValueError(
            "config keys 'randomization.servo_gain' and 'randomization.servo_force_limit' act on the asset's "
            "spring servos: leave them at their defaults with servo.model position or continuous"
        )


def _validate_track_starts(goal: GoalConfig) -> None:
    """``goal.track_starts``: only for spiral goals, below the number of checkpoints."""
    if goal.track_starts == 0:
        return
    if goal.mode != "spiral":
        raise ValueError(
            f"config key 'goal.track_starts' needs goal.mode 'spiral' (got {goal.mode!r}); 0 for other modes"
        )
    if not 0 < goal.track_starts < goal.num_checkpoints:
        raise ValueError(
            f"config key 'goal.track_starts' must be in 0..{goal.num_checkpoints - 1} "
            f"(num_checkpoints - 1), got {goal.track_starts!r}"
        )


def _validate_terrain(config: EnvConfig) -> None:
    """The terrain section, and how it fits the scene and the goal mode."""
    terrain = validate_terrain(config.terrain)
    types = terrain.types
    if config.scene == "flat" and types != ("flat",):
        raise ValueError(
            f"terrain types {list(types)} need a heightfield: set 'scene: terrain' (scene 'flat' is a plane)"
        )
    if config.reward.progress == "geodesic":
        _validate_geodesic(config)
    elif config.observation.path_direction:
        raise ValueError(
            "config key 'observation.path_direction' reads the goal sites' distance fields: it needs "
            f"reward.progress 'geodesic' (got {config.reward.progress!r})"
        )
    if "spiral" in types and config.goal.mode != "spiral":
        raise ValueError(
            f"the spiral terrain is a checkpoint track: it needs 'goal.mode: spiral', got {config.goal.mode!r}"
        )


def _validate_geodesic(config: EnvConfig) -> None:
    """Geodesic progress reads the goal sites' fields: terrain with reachability and goal sites, goals
    drawn at them (radial) or the spiral's checkpoints."""
    reach = config.terrain.reachability
    if config.scene != "terrain" or not reach.enabled:
        raise ValueError(
            "config key 'reward.progress' = 'geodesic' needs the terrain scene with terrain.reachability.enabled: true"
        )
    if config.goal.mode not in ("radial", "spiral"):
        raise ValueError(
            "config key 'reward.progress' = 'geodesic' needs goal.mode 'radial' or 'spiral' (goals at the "
            f"terrain's goal sites or the checkpoints), got {config.goal.mode!r}"
        )
    if config.goal.mode == "radial" and reach.goal_sites < 1:
        raise ValueError(
            "config key 'reward.progress' = 'geodesic' with radial goals needs terrain.reachability.goal_sites >= 1"
        )


def _get(config: Any, path: tuple[str, ...]) -> Any:
    for part in path:
        config = getattr(config, part)
    return config


def from_dict(data: Mapping[str, Any] | None, base: EnvConfig | None = None) -> EnvConfig:
    """Merge a nested mapping (older keys mapped, ``hsa_mjx.migrations``) over ``base`` (default: the
    defaults, the original's flat task) and build it (validated as it is built). Where the mapping names a
    ``robot``, that profile's keys go over ``base`` first and the mapping's own keys over them."""
    data = with_default_proportions(migrations.env_keys(dict(data or {}), GENERATOR_TYPES))
    layers = to_dict(base or EnvConfig())
    if "robot" in data:  # the profile over the base, the keys given beside it over both
        if not isinstance(data["robot"], str):
            raise ValueError(f"config key 'robot' must be a profile's name or file, got {data['robot']!r}")
        layers = merge(layers, robot_env(data["robot"], to_dict(EnvConfig())))
    return build_section(EnvConfig, merge(layers, data))


def to_dict(config: EnvConfig) -> dict:
    """The config as plain nested dicts and lists (YAML-ready)."""
    return plain(config)


def with_overrides(config: EnvConfig, **overrides: Any) -> EnvConfig:
    """Apply dotted-key overrides, e.g. ``**{"reward.forward": 3.0}`` or ``goal={"mode": "fixed"}``."""
    nested: dict = {}
    for dotted, value in overrides.items():
        parts = dotted.replace("__", ".").split(".")
        node = nested
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return from_dict(nested, base=config)


def load_config(path: str | Path) -> EnvConfig:
    """Load an environment config from a YAML file.

    The file may hold the env keys at its top level or under an ``env:`` section (training
    configs keep trainer settings beside it). Missing keys take the flat preset's values.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unknown keys, wrong types or invalid values (the message names the key).
    """
    data = read_yaml(path, "config file")
    if "env" in data:
        data = data["env"]
    return from_dict(data)


# The presets are the shipped env configs (configs/, package data once installed): each file states
# its task and what it changes from the defaults (the original's flat task). They are read on first use.
PRESET_FILES = {
    "flat": "flat.yaml",
    "craters": "craters.yaml",
    "corridor": "corridor.yaml",
    "spiral": "spiral.yaml",
    "mixed": "mixed_terrain.yaml",
}
# the flat task with the other goal rules (radial: the training configs' default, for the goal curriculum)
FLAT_GOAL_VARIANTS = {"flat_fixed_goal": "fixed", "flat_radial": "radial"}


class Presets(Mapping):
    """The presets by name, each built from its YAML file the first time it is asked for."""

    def __init__(self) -> None:
        self._built: dict[str, EnvConfig] = {}

    def __getitem__(self, name: str) -> EnvConfig:
        if name not in self._built:
            if name in PRESET_FILES:
                self._built[name] = load_config(data_dir("configs") / PRESET_FILES[name])
            elif name in FLAT_GOAL_VARIANTS:
                self._built[name] = with_overrides(self["flat"], name=name, goal__mode=FLAT_GOAL_VARIANTS[name])
            else:
                raise KeyError(name)
        return self._built[name]

    def __iter__(self) -> Iterator[str]:
        return iter((*PRESET_FILES, *FLAT_GOAL_VARIANTS))

    def __len__(self) -> int:
        return len(PRESET_FILES) + len(FLAT_GOAL_VARIANTS)


PRESETS = Presets()


def get_preset(name: str) -> EnvConfig:
    """Return a named preset or raise ValueError listing the presets."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; available presets: {sorted(PRESETS)}")
    return PRESETS[name]


__all__ = [
    "EnvConfig",
    "PhysicsConfig",
    "ControlConfig",
    "RewardConfig",
    "TerminationConfig",
    "GoalConfig",
    "TerrainConfig",
    "ObservationConfig",
    "PRESETS",
    "get_preset",
    "load_config",
    "from_dict",
    "to_dict",
    "with_overrides",
    "validate",
]

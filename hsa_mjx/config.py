"""Environment configuration: typed sections, YAML loading and presets (validation: ``config_checks``).

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
from hsa_mjx.config_checks import (
    BACKENDS,
    CONES,
    GOAL_MODES,
    HINGE_ANGLE_MODES,
    INTEGRATORS,
    MAX_HISTORY,
    PROGRESS_MODES,
    SCENES,
    SOLVERS,
    VELOCITY_MODES,
    validate,
)
from hsa_mjx.config_schema import build_section, plain
from hsa_mjx.randomization_config import ObservationNoiseConfig, RandomizationConfig
from hsa_mjx.resources import data_dir, merge, read_yaml
from hsa_mjx.robots import DEFAULT as DEFAULT_ROBOT
from hsa_mjx.robots import robot_env
from hsa_mjx.servo_config import ServoConfig
from hsa_mjx.terrain.height_scan import HeightScanConfig
from hsa_mjx.terrain.params import TERRAIN_TYPES as GENERATOR_TYPES
from hsa_mjx.terrain.params import TerrainConfig, with_default_proportions

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
    "BACKENDS",
    "CONES",
    "GOAL_MODES",
    "HINGE_ANGLE_MODES",
    "INTEGRATORS",
    "MAX_HISTORY",
    "PROGRESS_MODES",
    "SCENES",
    "SOLVERS",
    "VELOCITY_MODES",
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

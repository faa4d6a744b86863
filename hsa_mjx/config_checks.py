"""Validation of an environment config: the choices each key accepts and the ranges of its values.

``validate`` runs as every :class:`hsa_mjx.config.EnvConfig` is built (so no later code checks again):
a key out of its choices or range raises ``ValueError`` naming the key and the valid options.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hsa_mjx.config_schema import non_finite
from hsa_mjx.randomization_config import NOMINAL
from hsa_mjx.randomization_config import validate as validate_randomization
from hsa_mjx.robots import drawn_servos
from hsa_mjx.servo_config import resolve_servo
from hsa_mjx.servo_config import validate as validate_servo
from hsa_mjx.terrain.height_scan import validate as validate_height_scan
from hsa_mjx.terrain.params import validate_terrain

if TYPE_CHECKING:
    from hsa_mjx.config import EnvConfig, GoalConfig

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

"""The 24-value observation of the original, with block B's velocity read from the right dofs.

``hinge_angles`` picks how the first 8 values show the actuated hinge angles: ``raw`` (the
original), ``wrapped`` into [-pi, pi) or ``sincos`` (8 sines, then 8 cosines: 8 values more).
Optional entries, appended in this order when enabled (``ObservationConfig``):
``heading`` 4 values (the robot's heading and the goal direction in it), ``servo_targets`` 8 values
(the servo targets the actions increment), ``clock_period_s > 0`` 2 values (a gait clock),
``path_direction`` 2 values (the way the path to the goal leaves the robot, in its heading frame),
``height_scan`` one value per scan point (``hsa_mjx.terrain.height_scan``; the env reads it from its terrain),
``history_steps > 0`` the last observations (without scan) and actions (``hsa_mjx.task.history``;
the env appends them after :func:`observe`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

import hsa_mjx.terrain.height_scan
from hsa_mjx.config import ObservationConfig
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import RobotIndex
from hsa_mjx.task import history

OBSERVATION_SIZE = 24  # the original's observation (the default)
HEADING_EPS = 1e-8  # keeps the heading finite if the two block origins ever coincide
GOAL_EPS = 1e-8  # the goal direction's epsilon (the original's)
ORIGINAL = ObservationConfig()  # no optional entries: the original's 24 values
# Slot names in order: the original's 24, then each optional entry when enabled (``observe`` builds
# them in this order). The heading frame's goal direction is (x ahead, y left).
HINGE_ANGLE_LABELS = tuple(f"hinge_angle_{i}" for i in range(8))  # raw or wrapped
SINCOS_LABELS = tuple(f"hinge_sin_{i}" for i in range(8)) + tuple(f"hinge_cos_{i}" for i in range(8))
ORIGINAL_LABELS = (
    HINGE_ANGLE_LABELS
    + tuple(f"hinge_velocity_{i}" for i in range(8))
    + ("robot_x", "robot_y", "block_vx", "block_vy", "block_vz", "goal_distance", "goal_dir_x", "goal_dir_y")
)
HEADING_LABELS = ("heading_cos", "heading_sin", "goal_dir_ahead", "goal_dir_left")
SERVO_TARGET_LABELS = tuple(f"servo_target_{i}" for i in range(8))  # action-slot order
CLOCK_LABELS = ("clock_sin", "clock_cos")
PATH_LABELS = ("path_dir_ahead", "path_dir_left")


def core_labels(config: ObservationConfig) -> tuple[str, ...]:
    """The slots a history row repeats: every observation slot but the height scan and the history."""
    base = ORIGINAL_LABELS if config.hinge_angles != "sincos" else SINCOS_LABELS + ORIGINAL_LABELS[8:]
    return (
        base
        + (HEADING_LABELS if config.heading else ())
        + (SERVO_TARGET_LABELS if config.servo_targets else ())
        + (CLOCK_LABELS if config.clock_period_s > 0 else ())
        + (PATH_LABELS if config.path_direction else ())
    )


def observation_labels(config: ObservationConfig) -> tuple[str, ...]:
    """A short name per observation slot for this observation config, in order: ``observe``'s, then the history."""
    core = core_labels(config)
    return (
        core
        + hsa_mjx.terrain.height_scan.labels(config.height_scan)
        + history.labels(core, config.history_steps, len(SERVO_TARGET_LABELS))
    )


def observation_size(config: ObservationConfig) -> int:
    """Number of observation values for this observation config."""
    return len(observation_labels(config))


def robot_xy(data: mjx.Data, index: RobotIndex) -> jax.Array:
    """Robot position: midpoint of the two block frame origins in the XY plane (the original's "COM")."""
    return jnp.mean(data.xpos[index.block_body, :2], axis=0)


def joint_positions(data: mjx.Data, index: RobotIndex) -> jax.Array:
    """Angles of the 8 actuated hinges in action-slot order."""
    return data.qpos[index.joint_qpos]


def observed_hinge_angles(angles: jax.Array, mode: str) -> jax.Array:
    """The hinge angles as the observation shows them: ``raw``, ``wrapped`` into [-pi, pi) or ``sincos``."""
    if mode == "wrapped":
        return jnp.mod(angles + jnp.pi, 2.0 * jnp.pi) - jnp.pi
    if mode == "sincos":
        return jnp.concatenate([jnp.sin(angles), jnp.cos(angles)])
    return angles


def joint_velocities(data: mjx.Data, index: RobotIndex) -> jax.Array:
    """Velocities of the 8 actuated hinges in action-slot order."""
    return data.qvel[index.joint_qvel]


def base_velocity(data: mjx.Data, index: RobotIndex) -> jax.Array:
    """Mean world-frame linear velocity of the two blocks (the original mixed in block B's wrong dofs)."""
    lin = data.qvel[index.block_qvel[:, None] + jnp.arange(3)[None, :]]
    return jnp.mean(lin, axis=0)


def goal_vector(position: jax.Array, goal_xy: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Distance to the goal and the unit vector towards it (epsilon 1e-8 as in the original)."""
    delta = goal_xy - position
    distance = jnp.linalg.norm(delta)
    return distance, delta / (distance + GOAL_EPS)


def heading(data: mjx.Data, index: RobotIndex) -> jax.Array:
    """Unit vector (cos yaw, sin yaw) in the XY plane from block A's body origin to block B's."""
    block_a, block_b = data.xpos[index.block_body, :2]
    delta = block_b - block_a
    return delta / (jnp.linalg.norm(delta) + HEADING_EPS)


def to_heading_frame(vector: jax.Array, unit_heading: jax.Array) -> jax.Array:
    """A world XY vector in the heading frame (x along the heading, y to its left): rotated by -yaw."""
    cos, sin = unit_heading
    x, y = vector
    return jnp.stack([cos * x + sin * y, cos * y - sin * x])


def servo_targets(data: mjx.Data, index: RobotIndex) -> jax.Array:
    """The 8 position-servo targets (rad) in action-slot order: the state the actions increment."""
    return data.ctrl[index.servo_ids]


def gait_clock(time_s: jax.Array, period_s: float) -> jax.Array:
    """(sin, cos) of the phase 2 pi t / period; the phase is wrapped first so float32 stays exact."""
    cycles = jnp.asarray(time_s, jnp.float32) / period_s
    phase = 2.0 * jnp.pi * (cycles - jnp.floor(cycles))
    return jnp.stack([jnp.sin(phase), jnp.cos(phase)])


def observe(
    data: mjx.Data,
    goal_xy: jax.Array,
    index: RobotIndex,
    config: ObservationConfig = ORIGINAL,
    time_s: jax.Array | float = 0.0,
    height_scan: jax.Array | None = None,
    path_direction: jax.Array | None = None,
    tracked: tuple[jax.Array, jax.Array] | None = None,
) -> jax.Array:
    """Build the observation (float32): the original's 24 values, then the enabled optional entries.

    ``time_s`` is the episode time (env steps x dt), read only by the gait clock; ``height_scan`` the
    scan values (required when ``config.height_scan`` is on); ``path_direction`` the world-frame unit
    vector along the path to the goal (required when ``config.path_direction`` is on); ``tracked`` the
    position tracker's (xy, velocity) for the position and velocity entries (``velocity: differenced``;
    the goal entries stay the robot's own).
    """
    position = robot_xy(data, index)
    distance, direction = goal_vector(position, goal_xy)
    parts = [
        observed_hinge_angles(joint_positions(data, index), config.hinge_angles),
        joint_velocities(data, index),
        position if tracked is None else tracked[0],
        base_velocity(data, index) if tracked is None else tracked[1],
        distance[None],
        direction,
    ]
    if config.heading:
        unit_heading = heading(data, index)
        parts += [unit_heading, to_heading_frame(direction, unit_heading)]
    if config.servo_targets:
        parts.append(servo_targets(data, index))
    if config.clock_period_s > 0:
        parts.append(gait_clock(time_s, config.clock_period_s))
    if config.path_direction:
        if path_direction is None:
            raise ValueError("observation.path_direction is on: pass the path direction to observe()")
        parts.append(to_heading_frame(path_direction, heading(data, index)))
    if config.height_scan.enabled:
        if height_scan is None:
            raise ValueError("observation.height_scan is on: pass the scan values to observe()")
        parts.append(height_scan)
    return jnp.concatenate(parts).astype(jnp.float32)

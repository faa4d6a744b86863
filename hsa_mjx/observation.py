"""The 24-value observation of the original, with block B's velocity read from the right dofs."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from hsa_mjx.model import RobotIndex

OBSERVATION_SIZE = 24
# Slot layout: 0-7 hinge angles, 8-15 hinge velocities, 16-17 robot xy, 18-20 mean block linear
# velocity, 21 distance to goal, 22-23 unit vector to goal.


def robot_xy(data: mjx.Data, index: RobotIndex) -> jax.Array:
    """Robot position: midpoint of the two block frame origins in the XY plane (the original's "COM")."""
    return jnp.mean(data.xpos[index.block_body, :2], axis=0)


def joint_positions(data: mjx.Data, index: RobotIndex) -> jax.Array:
    """Angles of the 8 actuated hinges in action-slot order."""
    return data.qpos[index.joint_qpos]


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
    return distance, delta / (distance + 1e-8)


def observe(data: mjx.Data, goal_xy: jax.Array, index: RobotIndex) -> jax.Array:
    """Build the 24-value observation (float32)."""
    position = robot_xy(data, index)
    distance, direction = goal_vector(position, goal_xy)
    return jnp.concatenate([
        joint_positions(data, index),
        joint_velocities(data, index),
        position,
        base_velocity(data, index),
        distance[None],
        direction,
    ]).astype(jnp.float32)

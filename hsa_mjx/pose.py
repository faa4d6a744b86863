"""Rigid planar moves of the robot's spawn pose: a turn about the vertical and a shift in XY.

The robot has two free bodies (the blocks); everything else hangs off them, so moving the two
free joints moves the whole robot. Used to start spiral episodes along the track
(``goal.track_starts``); the original always spawns at the origin facing +x.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def yaw_quaternion(yaw: jax.Array) -> jax.Array:
    """Unit quaternion (w, x, y, z) of a turn by ``yaw`` radians about world z."""
    half = 0.5 * yaw
    return jnp.stack([jnp.cos(half), jnp.zeros_like(half), jnp.zeros_like(half), jnp.sin(half)])


def quaternion_product(a: jax.Array, b: jax.Array) -> jax.Array:
    """Hamilton product a * b of two (w, x, y, z) quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return jnp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def move_points(points: jax.Array, centre: jax.Array, target: jax.Array, yaw: jax.Array) -> jax.Array:
    """XY points (..., 2) turned by ``yaw`` about ``centre``, then shifted so ``centre`` lands on ``target``."""
    cos, sin = jnp.cos(yaw), jnp.sin(yaw)
    rel = points - centre
    turned = jnp.stack([cos * rel[..., 0] - sin * rel[..., 1], sin * rel[..., 0] + cos * rel[..., 1]], axis=-1)
    return turned + target


def move_free_joints(
    qpos: jax.Array, addresses: jax.Array, centre: jax.Array, target: jax.Array, yaw: jax.Array
) -> jax.Array:
    """``qpos`` with each free joint at ``addresses`` (position xyz, quaternion wxyz) moved rigidly:
    turned by ``yaw`` about the vertical through ``centre`` (XY), then shifted onto ``target``."""
    turn = yaw_quaternion(yaw)
    for adr in addresses.tolist():  # the robot's two blocks: a static, tiny loop
        xy = move_points(qpos[adr : adr + 2], centre, target, yaw)
        quat = quaternion_product(turn, qpos[adr + 3 : adr + 7])
        qpos = qpos.at[adr : adr + 2].set(xy).at[adr + 3 : adr + 7].set(quat)
    return qpos

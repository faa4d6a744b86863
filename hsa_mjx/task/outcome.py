"""What one env step concludes once the physics has run: how the episode ends (failure reasons,
success) and what the reward terms read (:class:`hsa_mjx.task.reward.RewardInputs`).

Pure functions of the step's before and after; ``HSAEnv.step`` wires them (``hsa_mjx.task.env``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from hsa_mjx.config import EnvConfig
from hsa_mjx.sim import physics
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import RobotIndex
from hsa_mjx.task import observation, reward, termination
from hsa_mjx.task.types import TaskState
from hsa_mjx.terrain.world import TerrainWorld


class Ending(NamedTuple):
    """How the step ends its episode: every reason's flag (``goal_reached`` included), and the totals."""

    reasons: dict[str, jax.Array]
    failed: jax.Array  # a failure reason (not the goal)
    success: jax.Array  # the goal (the spiral: its last checkpoint), without a failure
    terminated: jax.Array  # failed or succeeded


class Progress(NamedTuple):
    """Where the robot got to in the step, as the progress and stagnation terms read it."""

    velocity: jax.Array  # (2,) xy velocity over the step
    direction: jax.Array  # (2,) unit vector towards the goal (along the path with geodesic progress)
    distance: jax.Array  # () to the goal
    moved: jax.Array  # () displacement over the stagnation window
    window_full: jax.Array  # () the window holds enough positions
    collected: jax.Array  # () a spiral checkpoint collected this step
    completed: jax.Array  # () the spiral's last checkpoint collected


def judge(
    config: EnvConfig,
    index: RobotIndex,
    world: TerrainWorld,
    data: mjx.Data,
    stats: physics.SubstepStats,
    obs: jax.Array,
    xy: jax.Array,
    task: TaskState,
    completed: jax.Array,
) -> Ending:
    """The step's failure reasons (simulator health, heights over the ground, the arena) and success
    (within ``goal.success_radius`` of the goal; the spiral: its last checkpoint)."""
    ground = world.ground(task.tile, data.xpos[index.block_body, :2])
    finite = jnp.all(jnp.isfinite(obs))
    reasons = termination.failure_reasons(data, stats, finite, ground, config.termination, index)
    reasons["out_of_bounds"] = world.out_of_bounds(xy)
    failed = termination.any_reason(reasons)
    if config.goal.mode == "spiral":
        success = completed
    else:
        success = observation.goal_vector(xy, task.goal_xy)[0] < config.goal.success_radius
    reasons["goal_reached"] = success = success & jnp.logical_not(failed)
    return Ending(reasons, failed, success, failed | success)


def reward_inputs(
    config: EnvConfig,
    index: RobotIndex,
    data: mjx.Data,
    task: TaskState,
    action: jax.Array,
    heading_before: jax.Array,
    progress: Progress,
    ending: Ending,
) -> reward.RewardInputs:
    """What every reward term reads for this step (``task``: before its ``prev_*`` fields move on)."""
    return reward.RewardInputs(
        velocity=progress.velocity,
        goal_direction=progress.direction,
        action=action,
        prev_action=task.prev_action,
        joint_pos=observation.joint_positions(data, index),
        joint_vel=observation.joint_velocities(data, index),
        prev_joint_vel=task.prev_joint_vel,
        foot_force=physics.foot_forces(data, index.foot_sensors),
        distance=progress.distance,
        prev_distance=task.prev_distance,
        stagnation_progress=progress.moved,
        history_full=progress.window_full,
        checkpoint_collected=progress.collected,
        spiral_complete=progress.completed & ending.success,
        goal_reached=ending.success & (config.goal.mode != "spiral"),
        failed=ending.failed,
        terminated=ending.terminated,
        heading_before=heading_before,
        heading_after=observation.heading(data, index),
        dt=config.dt,
        rectified_forward=config.reward.forward_rectified,
        constraint_pairs=tuple(map(tuple, index.constraint_pairs.tolist())),
    )

"""Termination: named reasons evaluated on the state after a step, kept apart from truncation."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hsa_mjx.config import TerminationConfig
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import RobotIndex
from hsa_mjx.sim.physics import SubstepStats

FAILURE_REASONS = (
    "non_finite",
    "block_a_too_high",
    "block_a_too_low",
    "block_b_too_high",
    "block_b_too_low",
    "qvel_limit",
    "qacc_limit",
    "out_of_bounds",
)
REASONS = FAILURE_REASONS + ("goal_reached",)
# Two kinds of failure, reported apart: the simulator's state is unsound (non-finite, or velocities
# and accelerations beyond any physical meaning), or the robot failed its task (flipped, lifted off,
# sank, left the arena). A robot does not stop on the first kind; training and benchmarks may.
GROUPS = {
    "simulator_health": ("non_finite", "qvel_limit", "qacc_limit"),
    "task_failure": ("block_a_too_high", "block_a_too_low", "block_b_too_high", "block_b_too_low", "out_of_bounds"),
}


def failure_reasons(
    data: mjx.Data,
    stats: SubstepStats,
    obs_finite: jax.Array,
    ground_height: jax.Array,
    config: TerminationConfig,
    index: RobotIndex,
) -> dict[str, jax.Array]:
    """Each failure reason but ``out_of_bounds`` (the env adds it) as a bool.

    Block heights are measured from ``ground_height``: the surface under each block, shape (2,),
    or a scalar (0 on a plane).
    """
    z = data.xpos[index.block_body, 2] - ground_height
    qacc = stats.max_abs_qacc if config.qacc_every_substep else stats.final_abs_qacc
    return {
        "non_finite": stats.non_finite | jnp.logical_not(obs_finite),
        "block_a_too_high": z[0] > config.z_max,
        "block_a_too_low": z[0] < config.z_min,
        "block_b_too_high": z[1] > config.z_max,
        "block_b_too_low": z[1] < config.z_min,
        "qvel_limit": stats.max_abs_qvel > config.qvel_limit,
        "qacc_limit": qacc > config.qacc_limit if config.qacc_termination else jnp.zeros((), bool),
    }


def any_reason(reasons: dict[str, jax.Array]) -> jax.Array:
    """True when any reason holds."""
    return jnp.any(jnp.stack(list(reasons.values())))


def grouped(reasons: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """Whether any reason of each ``GROUPS`` kind holds (``simulator_health``, ``task_failure``)."""
    return {group: any_reason({name: reasons[name] for name in members}) for group, members in GROUPS.items()}

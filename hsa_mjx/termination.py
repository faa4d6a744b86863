"""Termination: named reasons evaluated on the state after a step, kept apart from truncation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct
from hsa_mjx.backend import mjx

from hsa_mjx.config import TerminationConfig
from hsa_mjx.model import RobotIndex

FAILURE_REASONS = (
    "non_finite", "block_a_too_high", "block_a_too_low", "block_b_too_high", "block_b_too_low",
    "qvel_limit", "qacc_limit", "out_of_bounds",
)
REASONS = FAILURE_REASONS + ("goal_reached",)


@struct.dataclass
class SubstepStats:
    """Worst values seen over the substeps of one env step (the original looked at the last only)."""

    max_abs_qvel: jax.Array
    max_abs_qacc: jax.Array
    non_finite: jax.Array  # bool: any NaN/Inf in qpos, qvel or qacc at any substep
    final_abs_qacc: jax.Array  # max |qacc| over the dofs at the last substep (the original's check)


def substep_stats(data: mjx.Data) -> SubstepStats:
    """Stats of one substep's state."""
    finite = (jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
              & jnp.all(jnp.isfinite(data.qacc)))
    qacc = jnp.max(jnp.abs(jnp.nan_to_num(data.qacc)))
    return SubstepStats(max_abs_qvel=jnp.max(jnp.abs(jnp.nan_to_num(data.qvel))), max_abs_qacc=qacc,
                        non_finite=jnp.logical_not(finite), final_abs_qacc=qacc)


def merge_stats(a: SubstepStats, b: SubstepStats) -> SubstepStats:
    """Worst of two substep stats (``b`` the later one: its final |qacc| is kept)."""
    return SubstepStats(jnp.maximum(a.max_abs_qvel, b.max_abs_qvel),
                        jnp.maximum(a.max_abs_qacc, b.max_abs_qacc), a.non_finite | b.non_finite,
                        b.final_abs_qacc)


def failure_reasons(data: mjx.Data, stats: SubstepStats, obs_finite: jax.Array,
                    ground_height: jax.Array, config: TerminationConfig,
                    index: RobotIndex) -> dict[str, jax.Array]:
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
        "qacc_limit": qacc > config.qacc_limit,
    }


def any_reason(reasons: dict[str, jax.Array]) -> jax.Array:
    """True when any reason holds."""
    return jnp.any(jnp.stack(list(reasons.values())))

"""Privileged critic inputs: what the simulator knows and a robot's sensors do not.

With a privileged critic (``ppo.privileged_critic``) the PPO value network reads these values after
the policy's observation; the policy, and every exported policy, never sees them. In order: the
noise-free height scan (when ``observation.height_scan`` is on), each block's true linear and
angular velocity (world frame, 12 values), the four feet's contact-force norms (N / 100), the
terrain type one-hot over ``hsa_mjx.terrain.TERRAIN_TYPES``, the tile's difficulty level as a
fraction of the top level and, when the env randomises anything (``randomization``), this episode's
true model (``hsa_mjx.task.randomization.true_model``: the physical scales, the inverse servo torque
limit and the action latency), which a policy can only infer.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hsa_mjx.config import ObservationConfig
from hsa_mjx.randomization_config import RandomizationConfig
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import RobotIndex
from hsa_mjx.sim.physics import foot_forces
from hsa_mjx.task.randomization import FOOT_MODEL_LABELS, TRUE_MODEL_LABELS, servo_model_labels
from hsa_mjx.terrain import height_scan
from hsa_mjx.terrain.params import TERRAIN_TYPES

FORCE_UNIT = 100.0  # N: contact forces are given in hundreds of newtons (resting feet carry ~12 N each)
BLOCK_DOFS = 6  # a free joint's velocity: linear (3), angular (3)
FEET = 4


NOTHING_DRAWN = RandomizationConfig()


def labels(config: ObservationConfig, randomization: RandomizationConfig = NOTHING_DRAWN) -> tuple[str, ...]:
    """A name per privileged value, in :func:`inputs`' order."""
    scan = tuple(f"clean_{name}" for name in height_scan.labels(config.height_scan))
    velocity = tuple(f"block_{b}_{kind}{axis}" for b in "ab" for kind in ("v", "w") for axis in "xyz")
    return (
        scan
        + velocity
        + tuple(f"foot_force_{i}" for i in range(FEET))
        + tuple(f"terrain_is_{name}" for name in TERRAIN_TYPES)
        + ("terrain_level",)
        + (TRUE_MODEL_LABELS if randomization.draws else ())
        + (FOOT_MODEL_LABELS if randomization.per_foot else ())
        + servo_model_labels(randomization)
    )


def size(config: ObservationConfig, randomization: RandomizationConfig = NOTHING_DRAWN) -> int:
    """Number of privileged values for this observation and randomisation config."""
    return len(labels(config, randomization))


def inputs(
    data: mjx.Data,
    index: RobotIndex,
    clean_scan: jax.Array,
    terrain_id: jax.Array,
    level_fraction: jax.Array,
    true_model: jax.Array,
) -> jax.Array:
    """The privileged values (float32); ``clean_scan``: the noise-free scan as the observation shapes it
    ((0,) when off); ``true_model``: the episode's model values ((0,) when nothing is randomised)."""
    block_velocity = data.qvel[index.block_qvel[:, None] + jnp.arange(BLOCK_DOFS)[None, :]].reshape(-1)
    parts = [
        clean_scan,
        block_velocity,
        foot_forces(data, index.foot_sensors) / FORCE_UNIT,
        jax.nn.one_hot(terrain_id, len(TERRAIN_TYPES)),
        jnp.reshape(level_fraction, (1,)),
        true_model,
    ]
    return jnp.concatenate([jnp.asarray(p, jnp.float32) for p in parts])

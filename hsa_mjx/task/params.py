"""Per-episode parameters: what a curriculum (or a caller) chooses for each env when it resets.

``EnvParams`` are traced arrays passed into ``HSAEnv.reset`` (gymnax's ``EnvParams``, here per env),
so one compiled reset serves any goal range and terrain cell: the training loop's curricula
produce a batch of them, everything else uses ``HSAEnv.default_params()``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

FREE_CELL = (-1, -1)  # terrain_cell that draws the tile's type and level from the terrain proportions


@struct.dataclass
class EnvParams:
    """One episode's parameters (leading batch axis for a batch of envs)."""

    goal_range: jax.Array  # (2,) float32: radial goal distance (min, max) in m, for goal.mode radial
    terrain_cell: jax.Array  # (2,) int32: (type row in terrain.types, level), or FREE_CELL
    # () float32 in [0, 1]: the share of each ``randomization`` range the episode draws from (1: all of it;
    # hsa_mjx.task.randomization.reset_state), as the randomisation curriculum widens it
    randomization_scale: jax.Array

    @staticmethod
    def make(goal_range, terrain_cell=FREE_CELL, randomization_scale=1.0) -> EnvParams:
        """Parameters from plain values (arrays of the right dtypes)."""
        return EnvParams(
            goal_range=jnp.asarray(goal_range, jnp.float32),
            terrain_cell=jnp.asarray(terrain_cell, jnp.int32),
            randomization_scale=jnp.asarray(randomization_scale, jnp.float32),
        )

    def repeat(self, batch: int) -> EnvParams:
        """The same parameters for every env of a batch (leading axis ``batch``)."""
        return jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), self)

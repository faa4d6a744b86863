"""The env's ground as one object: a plane, one terrain shared by every env, or a terrain per env.

The env keeps each env's heightfield data in its ``TaskState.terrain``; this class turns it into
the MJX model used for that env's physics, the spawn height, the ground under the blocks, the
field bounds and terrain-consistent goals. With a plane or a shared terrain the per-env field is
a (1,) placeholder and everything reads the shared data (a constant) instead.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from hsa_mjx.terrain.grid import Grid, inside, surface_height
from hsa_mjx.terrain.params import TERRAIN_TYPES, TerrainConfig
from hsa_mjx.terrain.placement import Footprint, corridor_line, onto_line
from hsa_mjx.terrain.sampler import TerrainSampler

PLACEHOLDER = (1,)  # TaskState.terrain on a plane or with a shared terrain
FLAT_ID = TERRAIN_TYPES.index("flat")
CORRIDOR_ID = TERRAIN_TYPES.index("corridor")


class TerrainWorld:
    """Static terrain set-up of one env (config, grid, sampler, footprint) and its pure helpers.

    Args:
        scene: ``"flat"`` (a plane: no terrain) or ``"terrain"`` (the heightfield scene).
        config: the ``terrain:`` section.
        mj_model: the loaded scene (the shared terrain is written into its ``hfield_data``).
        block_body: body ids of the two blocks.
    """

    def __init__(self, scene: str, config: TerrainConfig, mj_model: mujoco.MjModel, block_body: np.ndarray):
        self.config = config
        self.enabled = scene == "terrain"
        self.per_env = self.enabled and config.per_env
        if not self.enabled:
            return
        self.grid = Grid.from_model(mj_model)
        self.sampler = TerrainSampler(config, self.grid)
        self.footprint = Footprint.from_model(mj_model, block_body)
        self._corridor = "corridor" in config.types
        self.corridor_point, self.corridor_direction, self.corridor_limit = corridor_line(
            config.corridor, self.grid, config.edge_margin)
        if not self.per_env:
            data, type_id = jax.jit(self.sampler.sample)(jax.random.PRNGKey(config.seed))
            self.shared_data, self.shared_id = np.asarray(data), int(type_id)
            hid = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_HFIELD, "terrain")
            adr = mj_model.hfield_adr[hid]
            mj_model.hfield_data[adr:adr + self.grid.size] = self.shared_data

    def bake(self, model: mjx.Model) -> mjx.Model:
        """The MJX model every env shares: the shared terrain written in, else unchanged."""
        if self.enabled and not self.per_env:
            return model.replace(hfield_data=jnp.asarray(self.shared_data))
        return model

    def draw(self, key: jax.Array | None) -> tuple[jax.Array, jax.Array]:
        """This episode's (terrain field for TaskState, terrain type id); ``key`` only when per env."""
        if self.per_env:
            return self.sampler.sample(key)
        type_id = self.shared_id if self.enabled else FLAT_ID
        return jnp.zeros(PLACEHOLDER, jnp.float32), jnp.asarray(type_id, jnp.int32)

    def data(self, terrain: jax.Array) -> jax.Array:
        """The heightfield data of an env from its TaskState field (the shared data if shared)."""
        return terrain if self.per_env else jnp.asarray(self.shared_data)

    def model_for(self, model: mjx.Model, terrain: jax.Array) -> mjx.Model:
        """The MJX model for this env's physics: its own heightfield when terrain is per env."""
        return model.replace(hfield_data=terrain) if self.per_env else model

    def spawn_height(self, terrain: jax.Array, move: tuple | None = None) -> jax.Array:
        """Block-origin z resting the level robot on this env's surface (clearance from the config);
        ``move`` = (centre, target, yaw) for a spawn pose moved along the ground (``hsa_mjx.pose``)."""
        return self.footprint.spawn_height(self.data(terrain), self.grid, self.config.spawn_clearance, move)

    def ground(self, terrain: jax.Array, xy: jax.Array) -> jax.Array:
        """Surface height under the points ``xy`` (..., 2); 0 on a plane."""
        if not self.enabled:
            return jnp.zeros(xy.shape[:-1], jnp.float32)
        return surface_height(self.data(terrain), self.grid, xy)

    def out_of_bounds(self, xy: jax.Array) -> jax.Array:
        """True when the robot position is closer than ``edge_margin`` to the field's edge (never on a plane)."""
        if not self.enabled:
            return jnp.zeros((), bool)
        return jnp.logical_not(inside(self.grid, xy, self.config.edge_margin))

    def place_goal(self, goal_xy: jax.Array, terrain_id: jax.Array) -> jax.Array:
        """Keep goals on the floor: on a corridor env the goal moves onto the corridor's centre line."""
        if not (self.enabled and self._corridor):
            return goal_xy
        on_line = onto_line(goal_xy, jnp.asarray(self.corridor_point), jnp.asarray(self.corridor_direction),
                            self.corridor_limit)
        return jnp.where(terrain_id == CORRIDOR_ID, on_line, goal_xy)

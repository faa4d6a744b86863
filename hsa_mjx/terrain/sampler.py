"""The dispatcher, the flat spawn zone, and per-env terrain drawing for a configured mixture of types."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.terrain.generators import GENERATORS, point_height, vertex_mesh
from hsa_mjx.terrain.grid import Grid, to_hfield_data
from hsa_mjx.terrain.params import (
    RANDOM_TYPES,
    TERRAIN_TYPES,
    FlatSpawnConfig,
    TerrainConfig,
    check_type,
)

SPAWN_BLEND = 1.2  # the zone blends back into the terrain between radius and 1.2 x radius
PLANE_STEP = 0.05  # m: the central differences that give the terrain's slope at the zone centre
PLANAR = 0.005  # m: the terrain under the zone lies on its tangent plane within this: the zone follows the plane


def generate(
    terrain_type: str, key: jax.Array, params: Any = None, grid: Grid = Grid(), difficulty: float | jax.Array = 1.0
) -> jax.Array:
    """World heights (nrow, ncol) of one terrain of ``terrain_type``, relative to its level 0.

    Args:
        terrain_type: one of ``TERRAIN_TYPES``.
        key: PRNG key (only perlin, craters and poles use it).
        params: the type's parameter dataclass; ``None`` takes the defaults.
        grid: the heightfield's static grid (default: the asset's 50 x 50 over 10 x 10 m).
        difficulty: in [0, 1], a float or a traced scalar: 0 is level ground, 1 the terrain the
            parameters describe (``generators.DIFFICULTY_PARAMETER`` says what it scales).

    Raises:
        ValueError: unknown ``terrain_type`` (the message lists the valid types).
    """
    check_type(terrain_type)
    params = TerrainConfig().params(terrain_type) if params is None else params
    x, y = vertex_mesh(grid)
    return GENERATORS[terrain_type](key, params, grid, x, y, difficulty).astype(jnp.float32)


def spawn_plane(
    terrain_type: str, params: Any, grid: Grid, spawn: FlatSpawnConfig, difficulty: float | jax.Array = 1.0
) -> jax.Array:
    """The terrain's tangent plane at the spawn zone's centre, (height, slope along x, slope along y), for
    the deterministic types (slopes: central differences over ``PLANE_STEP``); level 0 for the random
    ones, whose obstacles the zone removes as the original did. :func:`apply_flat_spawn` follows it where
    the terrain under the zone is that plane (an incline), else levels the zone at its height."""
    if terrain_type in RANDOM_TYPES:
        return jnp.zeros((3,), jnp.float32)
    cx, cy = grid.fraction_to_x(spawn.center[0]), grid.fraction_to_y(spawn.center[1])
    fn, h = GENERATORS[terrain_type], PLANE_STEP

    def at(x: float, y: float) -> jax.Array:
        return point_height(fn, params, grid, x, y, difficulty)

    slope_x = (at(cx + h, cy) - at(cx - h, cy)) / (2.0 * h)
    slope_y = (at(cx, cy + h) - at(cx, cy - h)) / (2.0 * h)
    return jnp.stack([at(cx, cy), slope_x, slope_y]).astype(jnp.float32)


def apply_flat_spawn(heights: jax.Array, grid: Grid, spawn: FlatSpawnConfig, plane: jax.Array) -> jax.Array:
    """Level a disc of ``spawn.radius`` (fraction of the field width), blending back into the terrain
    linearly out to 1.2 x the radius: to ``plane`` (height, slope x, slope y at the centre:
    :func:`spawn_plane`) where the terrain under the blended disc lies on it within ``PLANAR`` (an incline
    passes through unchanged), else to the plane's height, level (stairs, waves, obstacles)."""
    radius = spawn.radius * 2.0 * grid.half_x
    if not spawn.enabled or radius <= 0.0:
        return heights
    x, y = vertex_mesh(grid)
    dx, dy = x - grid.fraction_to_x(spawn.center[0]), y - grid.fraction_to_y(spawn.center[1])
    tilted = plane[0] + plane[1] * dx + plane[2] * dy
    blend = jnp.clip((jnp.hypot(dx, dy) - radius) / ((SPAWN_BLEND - 1.0) * radius), 0.0, 1.0)
    planar = jnp.max(jnp.where(blend < 1.0, jnp.abs(heights - tilted), 0.0)) <= PLANAR
    level = jnp.where(planar, tilted, plane[0])
    return jnp.where(blend < 1.0, level + (heights - level) * blend, heights)


class TerrainSampler:
    """Draws one env's terrain from a key: its type (from the configured proportions), heights,
    flat spawn zone and the [0, 1] heightfield data. Everything static comes from the config.

    ``sample(key) -> (data (nrow * ncol,) float32, type_id () int32)``; ``type_id`` indexes
    ``TERRAIN_TYPES``. With several types the generators are selected with ``lax.switch`` (under
    ``vmap`` every configured generator runs and the result is selected per env). Terrain is drawn
    at ``config.difficulty`` unless a difficulty is given.
    """

    def __init__(self, config: TerrainConfig, grid: Grid):
        self.config, self.grid = config, grid
        self.types = tuple(config.types)
        self.type_ids = jnp.asarray([TERRAIN_TYPES.index(t) for t in self.types], jnp.int32)
        self.log_p = jnp.log(jnp.asarray(np.asarray(config.proportions, np.float64) + 1e-30, jnp.float32))
        self._branches = [self._branch(t) for t in self.types]

    def _branch(self, terrain_type: str):
        """One type's levelled heights as a function of (key, difficulty) (a lax.switch branch)."""
        params, grid, spawn = self.config.params(terrain_type), self.grid, self.config.flat_spawn

        def branch(key: jax.Array, difficulty: jax.Array) -> jax.Array:
            heights = generate(terrain_type, key, params, grid, difficulty)
            return apply_flat_spawn(heights, grid, spawn, spawn_plane(terrain_type, params, grid, spawn, difficulty))

        return branch

    def heights(self, key: jax.Array, difficulty: float | jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
        """World heights (nrow, ncol) with the spawn zone applied, and the local type index."""
        difficulty = jnp.asarray(self.config.difficulty if difficulty is None else difficulty, jnp.float32)
        k_type, k_gen = jax.random.split(key)
        if len(self.types) == 1:
            return self._branches[0](k_gen, difficulty), jnp.zeros((), jnp.int32)
        index = jax.random.categorical(k_type, self.log_p).astype(jnp.int32)
        return jax.lax.switch(index, self._branches, k_gen, difficulty), index

    def type_data(self, index: int, key: jax.Array, difficulty: float | jax.Array | None = None) -> jax.Array:
        """Heightfield data (nrow * ncol,) in [0, 1] of the ``index``-th configured type (a static index)."""
        difficulty = jnp.asarray(self.config.difficulty if difficulty is None else difficulty, jnp.float32)
        return to_hfield_data(self._branches[index](key, difficulty), self.grid)

    def sample(self, key: jax.Array, difficulty: float | jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
        """Heightfield data (nrow * ncol,) in [0, 1] and the type id (index into ``TERRAIN_TYPES``)."""
        heights, index = self.heights(key, difficulty)
        return to_hfield_data(heights, self.grid), self.type_ids[index]

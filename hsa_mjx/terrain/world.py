"""The env's ground as one object: a plane, or this episode's tile of the run's terrain atlas.

Each env keeps the index of its tile in ``TaskState.tile``. This class draws it at reset, puts the
floor's mocap body where that tile lies under the world origin, and answers everything the env
asks of the ground in the tile's own coordinates: the spawn height, the surface under the blocks,
the field bounds and terrain-consistent goals. On the plane scene the tile is a placeholder 0 and
the ground is z = 0.
"""

from __future__ import annotations

import copy
import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.terrain import geodesic, reachability, traversability
from hsa_mjx.terrain.atlas import TerrainPool
from hsa_mjx.terrain.grid import inside, surface_height
from hsa_mjx.terrain.params import TERRAIN_TYPES, TerrainConfig
from hsa_mjx.terrain.placement import Footprint, corridor_line, onto_line
from hsa_mjx.terrain.regeneration import TerrainTiles, initial_tiles

FLAT_ID = TERRAIN_TYPES.index("flat")
CORRIDOR_ID = TERRAIN_TYPES.index("corridor")


class TerrainWorld:
    """Static terrain set-up of one env (pool, footprint, corridor line) and its pure helpers.

    Args:
        config: the ``terrain:`` section.
        pool: the run's terrain tiles (``hsa_mjx.sim.model.load_scene``); None on the plane scene.
        mj_model: the loaded scene (for the robot's footprint).
        block_body: body ids of the two blocks.
    """

    def __init__(
        self,
        config: TerrainConfig,
        pool: TerrainPool | None,
        mj_model: mujoco.MjModel,
        block_body: np.ndarray,
        site_points: np.ndarray | None = None,
    ):
        """``site_points`` (count, 2): put these goal sites (the spiral's checkpoints) on every tile instead
        of drawing ``terrain.reachability.goal_sites`` per tile."""
        self.config, self.pool = config, pool
        self.enabled = pool is not None
        self.sites: geodesic.GoalSites | None = None
        self.tiles: TerrainTiles | None = None  # the pool's device arrays the env reads (replaced by with_tiles)
        self.alternating = False  # tiles re-drawn in two halves: new episodes draw the newer (with_tiles)
        if not self.enabled:
            return
        self.grid = pool.layout.tile  # one tile: the original field, in the robot's coordinates
        self._atlas_grid = pool.layout.grid
        self._centres = jnp.asarray(pool.centres)
        self.footprint = Footprint.from_model(mj_model, block_body)
        self._corridor = "corridor" in config.types
        self.corridor_point, self.corridor_direction, self.corridor_limit = corridor_line(
            config.corridor, self.grid, config.edge_margin
        )
        if pool.reach is not None:
            self._cells = reachability.cell_centres(self.grid, config.reachability.resolution)
            if config.reachability.goal_sites > 0 or site_points is not None:
                self._build_sites(site_points)
        self.tiles = initial_tiles(pool, self.sites)

    def _build_sites(self, points: np.ndarray | None) -> None:
        """Every tile's goal sites and their distance fields (``hsa_mjx.terrain.geodesic``), on the device."""
        reach = self.config.reachability
        limits = dataclasses.replace(traversability.ROBOT, resolution=reach.resolution)
        count = reach.goal_sites if points is None else len(points)
        spec = geodesic.SiteSpec(self.grid, limits, reach.goal_range, count, reach.field_stride)
        key = jax.random.fold_in(jax.random.PRNGKey(self.config.seed), 7)
        self.site_spec = spec
        self.sites = geodesic.build(spec, self.pool.tiles, self.pool.reach, key, points)

    def with_tiles(self, tiles: TerrainTiles) -> TerrainWorld:
        """This world reading the pool's arrays from ``tiles`` (traced; ``hsa_mjx.terrain.regeneration``), new
        episodes drawing a random type's tile among the half its latest re-draw wrote."""
        world = copy.copy(self)
        world.tiles, world.alternating = tiles, True
        return world

    @property
    def has_sites(self) -> bool:
        """Whether every tile carries goal sites with distance fields (geodesic progress)."""
        return self.sites is not None

    def site_goal(
        self, key: jax.Array, tile: jax.Array, goal_range: jax.Array, bearing_deg: tuple[float, float]
    ) -> tuple[jax.Array, jax.Array]:
        """(site index, goal xy): a site of ``tile`` drawn uniformly among those at a path distance in
        ``goal_range`` (traced) and a bearing in ``bearing_deg`` (static); site -1 and the spawn-nearest
        site's position where none qualifies."""
        spawn, xy = self.tiles.site_spawn[tile], self.tiles.site_xy[tile]
        bearing = jnp.degrees(jnp.abs(jnp.arctan2(xy[:, 1], xy[:, 0])))
        ok = (spawn >= goal_range[0]) & (spawn <= goal_range[1])
        ok = ok & (bearing >= bearing_deg[0]) & (bearing <= bearing_deg[1])
        site = jax.random.categorical(key, jnp.where(ok, 0.0, -jnp.inf)).astype(jnp.int32)
        site = jnp.where(jnp.any(ok), site, -1)
        return site, xy[jnp.maximum(site, 0)]

    def path_to_goal(self, tile: jax.Array, site: jax.Array, xy: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(path distance, unit direction of the path) from ``xy`` to goal site ``site`` of ``tile``."""
        field = self.tiles.site_fields[tile, site]
        origin, spacing = self.sites.origin, self.sites.spacing
        return geodesic.field_distance(field, origin, spacing, xy), geodesic.path_direction(field, origin, spacing, xy)

    @property
    def reachable_goals(self) -> bool:
        """Whether goals are drawn on the ground the robot reaches (``terrain.reachability.enabled``)."""
        return self.enabled and self.pool.reach is not None

    def reachable_goal(
        self,
        key: jax.Array,
        tile: jax.Array,
        goal_range: jax.Array,
        bearing_deg: tuple[float, float],
        fallback: jax.Array,
    ) -> jax.Array:
        """A goal on ``tile`` at a path distance in ``goal_range`` from the spawn, within ``bearing_deg``
        (static: its cells are found once, on the host; ``reachability.reachable_goal``); ``fallback`` where
        the tile has no such ground."""
        allowed = jnp.asarray(reachability.bearing_mask(self._cells, bearing_deg))
        cells = jnp.asarray(self._cells)
        return reachability.reachable_goal(key, self.tiles.reach[tile], cells, allowed, goal_range, fallback)

    @property
    def per_env(self) -> bool:
        """Whether envs draw their own tile (a pool of terrains) rather than share one."""
        return self.enabled and self.config.per_env

    def draw(self, key: jax.Array | None, cell: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
        """This episode's (tile index, terrain type id); ``key`` and ``cell`` = (type row, level), or (-1, -1)
        (or None) to draw both by the proportions, are used only when envs draw their own."""
        if self.per_env:
            return self.pool.draw(key, cell, self.tiles.generation % 2 if self.alternating else None)
        type_id = int(self.pool.tile_type[0]) if self.enabled else FLAT_ID
        return jnp.zeros((), jnp.int32), jnp.asarray(type_id, jnp.int32)

    def floor_position(self, tile: jax.Array) -> jax.Array:
        """Where the floor's mocap body goes so that ``tile``'s centre lies under the world origin, (3,)."""
        return jnp.concatenate([-self._centres[tile], jnp.zeros(1, jnp.float32)])

    def spawn_height(self, tile: jax.Array, move: tuple | None = None) -> jax.Array:
        """Block-origin z resting the level robot on this env's surface (clearance from the config);
        ``move`` = (centre, target, yaw) for a spawn pose moved along the ground (``hsa_mjx.pose``)."""
        return self.footprint.spawn_height(lambda xy: self.ground(tile, xy), self.config.spawn_clearance, move)

    def ground(self, tile: jax.Array, xy: jax.Array) -> jax.Array:
        """Surface height under the points ``xy`` (..., 2) of this env's tile; 0 on a plane."""
        if not self.enabled:
            return jnp.zeros(xy.shape[:-1], jnp.float32)
        return surface_height(self.tiles.atlas, self._atlas_grid, xy + self._centres[tile])

    def level_fraction(self, tile: jax.Array) -> jax.Array:
        """The difficulty level of ``tile`` as a fraction of the top level (0 on a plane or with one level)."""
        levels = self.config.levels if self.enabled else 1
        if levels <= 1:
            return jnp.zeros((), jnp.float32)
        return jnp.asarray(self.pool.tile_level, jnp.float32)[tile] / (levels - 1)

    def out_of_bounds(self, xy: jax.Array) -> jax.Array:
        """True when the robot position is closer than ``edge_margin`` to its tile's edge (never on a plane)."""
        if not self.enabled:
            return jnp.zeros((), bool)
        return jnp.logical_not(inside(self.grid, xy, self.config.edge_margin))

    def place_goal(self, goal_xy: jax.Array, terrain_id: jax.Array) -> jax.Array:
        """Keep goals on the floor: on a corridor env the goal moves onto the corridor's centre line."""
        if not (self.enabled and self._corridor):
            return goal_xy
        on_line = onto_line(
            goal_xy, jnp.asarray(self.corridor_point), jnp.asarray(self.corridor_direction), self.corridor_limit
        )
        return jnp.where(terrain_id == CORRIDOR_ID, on_line, goal_xy)

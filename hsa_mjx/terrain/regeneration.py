"""Fresh terrain during training: the random types' tiles re-drawn on the device, so no pool is memorised.

The run's pool (``hsa_mjx.terrain.atlas``) is drawn once from ``terrain.seed``. With regeneration the
arrays the env reads of it, the atlas heightfield, the path-distance fields of goals on reachable ground
and the goal sites with their distance fields, become a :class:`TerrainTiles` pytree that the batch
carries (``hsa_mjx.batch.auto_reset``) and :func:`regenerate` replaces: every tile of a random type
(perlin, craters, poles) is drawn again at its level from a new key, mapped, and kept only where it
holds the goal ground ``terrain.reachability`` asks for (a failing draw leaves the old tile in place:
a tile that fails is never shipped). The deterministic types do not change. It all runs in one jitted
function on the device, between PPO iterations; the env reads the tiles through
``HSAEnv.with_terrain``.

No tile changes under a running episode: the tiles of each random cell are two halves, and a re-draw
writes the half that new episodes stopped drawing at the re-draw before, then sends new episodes
there (``TerrainWorld.draw``). An episode still running on the half being written (one that started
two re-draws ago: only where the re-draw period is shorter than an episode) is truncated first
(``AutoResetEnv.tick``), so its goal, its goal site's distance field and the ground under it always
belong to the same tile.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hsa_mjx.terrain import geodesic, reachability, traversability
from hsa_mjx.terrain.params import RANDOM_TYPES
from hsa_mjx.terrain.sampler import TerrainSampler


@struct.dataclass
class TerrainTiles:
    """The pool's arrays the env reads (device arrays); fields the pool lacks are empty (size 0).

    ``atlas`` (atlas vertices,) the heightfield data; ``reach`` (tiles, n, n) path distances from the
    spawn; ``site_xy`` (tiles, K, 2), ``site_spawn`` (tiles, K) and ``site_fields`` (tiles, K, m, m) the
    goal sites; ``generation`` () int32 how many times the random tiles were re-drawn, ``age`` () int32
    training iterations since the last time.
    """

    atlas: jax.Array
    reach: jax.Array
    site_xy: jax.Array
    site_spawn: jax.Array
    site_fields: jax.Array
    generation: jax.Array
    age: jax.Array


def _empty() -> jax.Array:
    return jnp.zeros((0,), jnp.float32)


def initial_tiles(pool, sites: geodesic.GoalSites | None) -> TerrainTiles:
    """The arrays of ``pool`` (``atlas.TerrainPool``) and its goal ``sites`` as built, generation 0."""
    return TerrainTiles(
        atlas=jnp.asarray(pool.atlas),
        reach=_empty() if pool.reach is None else jnp.asarray(pool.reach),
        site_xy=_empty() if sites is None else jnp.asarray(sites.xy),
        site_spawn=_empty() if sites is None else jnp.asarray(sites.spawn_distance),
        site_fields=_empty() if sites is None else jnp.asarray(sites.fields),
        generation=jnp.zeros((), jnp.int32),
        age=jnp.zeros((), jnp.int32),
    )


class Regenerator:
    """Re-draws the random tiles of one env's pool (static layout, config and limits)."""

    def __init__(self, world):
        pool = world.pool
        if pool is None or not pool.config.per_env:
            raise ValueError("terrain regeneration needs per-env terrain (scene 'terrain', terrain.per_env: true)")
        self.world, self.config, self.layout = world, pool.config, pool.layout
        self.sampler = TerrainSampler(self.config, self.layout.tile)
        reach = self.config.reachability
        self.limits = dataclasses.replace(traversability.ROBOT, resolution=reach.resolution)
        first = np.cumsum((0,) + tuple(c * self.layout.levels for c in self.layout.counts[:-1]))
        self.rows = [  # (row, first tile, tile count) of every random type's row
            (r, int(first[r]), self.layout.counts[r] * self.layout.levels)
            for r, name in enumerate(self.layout.types)
            if name in RANDOM_TYPES
        ]
        self.difficulty = np.asarray(self.layout.difficulties, np.float32)[self.layout.tile_level()]
        self.tile_half = self.layout.tile_half()
        self.random_tile = np.zeros(len(self.tile_half), bool)
        for _, first, count in self.rows:
            self.random_tile[first : first + count] = True
        small = [self.layout.types[r] for r, _, _ in self.rows if self.layout.counts[r] < 2]
        if small:
            raise ValueError(
                f"terrain regeneration needs terrain.tiles_per_type >= 2 (the tiles of a cell are two halves that "
                f"take turns, so that no tile changes under a running episode); {small} have fewer"
            )

    @property
    def random_tiles(self) -> int:
        """How many tiles a regeneration re-draws."""
        return sum(count for _, _, count in self.rows)

    def stale(self, tiles: TerrainTiles, tile: jax.Array) -> jax.Array:
        """Whether ``tile`` (any shape of indices) was re-written by the last re-draw: episodes on it that
        started before that re-draw stand on ground that changed (``AutoResetEnv.tick`` truncates them)."""
        half = jnp.asarray(self.tile_half)[tile]
        return jnp.asarray(self.random_tile)[tile] & (half == tiles.generation % 2) & (tiles.generation > 0)

    def regenerate(self, key: jax.Array, tiles: TerrainTiles) -> TerrainTiles:
        """The random tiles of the half that new episodes stopped drawing at the last re-draw drawn again from
        ``key`` (kept where they pass the reachability check); new episodes then draw them."""
        t = self.layout.tile
        atlas = tiles.atlas.reshape(self.layout.rows * t.nrow, self.layout.cols * t.ncol)
        half = (tiles.generation + 1) % 2  # the half written now, drawn from the next generation on
        for row, first, count in self.rows:
            index = np.arange(first, first + count)
            keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.asarray(index))
            data = jax.vmap(lambda k, d, r=row: self.sampler.type_data(r, k, d))(keys, self.difficulty[index])
            accept, fields = jnp.asarray(self.tile_half[index]) == half, None
            if tiles.reach.size:
                fields = jax.vmap(lambda d: reachability.spawn_field(d, t, self.limits))(data)
                reach = self.config.reachability
                area = jnp.sum((fields >= reach.goal_range[0]) & (fields <= reach.goal_range[1]), axis=(1, 2))
                accept = accept & (area * reach.resolution**2 >= reach.min_area)
                tiles = tiles.replace(reach=tiles.reach.at[index].set(_keep(accept, fields, tiles.reach[index])))
            if tiles.site_fields.size:
                tiles = self._new_sites(tiles, index, keys, data, fields, accept)
            for j, (r, c) in enumerate(self.layout.slots()[first : first + count]):
                block = atlas[r * t.nrow : (r + 1) * t.nrow, c * t.ncol : (c + 1) * t.ncol]
                new = jnp.where(accept[j], data[j].reshape(t.nrow, t.ncol), block)
                atlas = atlas.at[r * t.nrow : (r + 1) * t.nrow, c * t.ncol : (c + 1) * t.ncol].set(new)
        return tiles.replace(atlas=atlas.reshape(-1), generation=tiles.generation + 1)

    def _new_sites(
        self,
        tiles: TerrainTiles,
        index: np.ndarray,
        keys: jax.Array,
        data: jax.Array,
        spawn_fields: jax.Array,
        accept: jax.Array,
    ) -> TerrainTiles:
        """The goal sites and fields of the re-drawn tiles (the accepted ones replace the old)."""
        spec = self.world.site_spec

        def one(d, field, k):
            return geodesic.tile_sites(spec, d, field, jax.random.fold_in(k, 7))

        xy, spawn, fields = jax.vmap(one)(data, spawn_fields, keys)
        return tiles.replace(
            site_xy=tiles.site_xy.at[index].set(_keep(accept, xy, tiles.site_xy[index])),
            site_spawn=tiles.site_spawn.at[index].set(_keep(accept, spawn, tiles.site_spawn[index])),
            site_fields=tiles.site_fields.at[index].set(_keep(accept, fields, tiles.site_fields[index])),
        )


def _keep(accept: jax.Array, new: jax.Array, old: jax.Array) -> jax.Array:
    """``new`` where ``accept`` (one flag per leading entry), else ``old``."""
    return jnp.where(accept.reshape((-1,) + (1,) * (new.ndim - 1)), new, old)

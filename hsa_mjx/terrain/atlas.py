"""Per-env terrain as tiles of one shared heightfield (an atlas), placed under each env by a mocap body.

MuJoCo Warp keeps one ``hfield_data`` for every world it simulates, and ``geom_dataid`` is static in
both MJX implementations, so envs cannot each carry their own heightfield. Instead the run draws a
pool of terrains once (per difficulty level, ``tiles_per_type`` of each random type and one of each
deterministic type; or a single shared one), lays them out as tiles of one large heightfield, and
each env, at every reset, draws a tile and moves the floor's mocap body (``terrain_frame``) so that
its tile's centre lies under the world origin. The robot, its goals and every height query stay in the
tile's own coordinates, exactly those of the original 10 x 10 m field: the same code serves a plane,
one terrain, or a pool.

Layout: one row of tiles per configured type (rows along world y); along a row (x) the tiles of level
0, then those of level 1, and so on. Tiles do not share vertices (a 1-cell seam joins neighbours),
so each tile's data is exactly what its generator produced.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.terrain import reachability, traversability
from hsa_mjx.terrain.grid import Grid
from hsa_mjx.terrain.params import RANDOM_TYPES, TERRAIN_TYPES, TerrainConfig
from hsa_mjx.terrain.sampler import TerrainSampler


@dataclasses.dataclass(frozen=True)
class AtlasLayout:
    """How many tiles of which type, and where each sits in the atlas heightfield.

    Args:
        tile: the grid of one tile (the asset's field).
        types: the terrain type of each row of tiles.
        counts: tiles of each row per difficulty level (the rest of a row stays flat, never drawn).
        difficulties: the difficulty of each level.
    """

    tile: Grid
    types: tuple[str, ...]
    counts: tuple[int, ...]
    difficulties: tuple[float, ...] = (1.0,)

    @classmethod
    def from_config(cls, config: TerrainConfig, tile: Grid) -> AtlasLayout:
        """One row per type: per level ``tiles_per_type`` tiles of a random type, one of a deterministic
        type; a single tile when the terrain is shared (``per_env: false``)."""
        if not config.per_env:
            return cls(tile, ("shared",), (1,), (config.difficulty,))
        counts = tuple(config.tiles_per_type if t in RANDOM_TYPES else 1 for t in config.types)
        return cls(tile, tuple(config.types), counts, config.level_difficulties)

    @property
    def levels(self) -> int:
        return len(self.difficulties)

    @property
    def rows(self) -> int:
        return len(self.counts)

    @property
    def cols(self) -> int:
        return max(self.counts) * self.levels

    @property
    def grid(self) -> Grid:
        """The atlas heightfield: ``rows x cols`` tiles at the tile's vertex spacing."""
        nrow, ncol = self.rows * self.tile.nrow, self.cols * self.tile.ncol
        return Grid(
            nrow,
            ncol,
            0.5 * (ncol - 1) * self.tile.spacing_x,
            0.5 * (nrow - 1) * self.tile.spacing_y,
            self.tile.z_scale,
            self.tile.base,
        )

    def slots(self) -> list[tuple[int, int]]:
        """(row, col) of every drawable tile, in tile-index order (row by row, level by level)."""
        return [(r, c) for r, count in enumerate(self.counts) for c in range(count * self.levels)]

    def tile_level(self) -> np.ndarray:
        """The difficulty level of every tile, (tiles,) int32."""
        return np.asarray([c // self.counts[r] for r, c in self.slots()], np.int32)

    def tile_half(self) -> np.ndarray:
        """Which half of its cell every tile is in (0: even position, 1: odd), (tiles,) int32: the halves that
        take turns when tiles are re-drawn (``TerrainPool.draw``'s ``half``, ``hsa_mjx.terrain.regeneration``)."""
        return np.asarray([c % self.counts[r] % 2 for r, c in self.slots()], np.int32)

    def centres(self) -> np.ndarray:
        """Each tile's centre in the atlas frame, (tiles, 2): where the floor moves to put it at the origin."""
        atlas, tile = self.grid, self.tile
        out = [
            (
                -atlas.half_x + (c * tile.ncol + 0.5 * (tile.ncol - 1)) * tile.spacing_x,
                -atlas.half_y + (r * tile.nrow + 0.5 * (tile.nrow - 1)) * tile.spacing_y,
            )
            for r, c in self.slots()
        ]
        return np.asarray(out, np.float32)

    def assemble(self, tiles: np.ndarray) -> np.ndarray:
        """The atlas data (nrow * ncol,) from the tiles' data (tiles, tile nrow * ncol), row-major."""
        t = self.tile
        atlas = np.zeros((self.rows * t.nrow, self.cols * t.ncol), np.float32)
        for (r, c), data in zip(self.slots(), tiles):
            atlas[r * t.nrow : (r + 1) * t.nrow, c * t.ncol : (c + 1) * t.ncol] = np.asarray(data).reshape(
                t.nrow, t.ncol
            )
        return atlas.reshape(-1)


class TerrainPool:
    """The run's terrain tiles: their data, types and centres, and the per-episode draw.

    ``draw(key, cell) -> (tile index, type id)``: a tile of the given ``cell`` = (type row, level),
    or, without one, the type from the configured proportions and (with several levels) a level
    uniformly; then one of that cell's tiles uniformly. With a shared terrain: always tile 0.
    """

    def __init__(
        self,
        config: TerrainConfig,
        layout: AtlasLayout,
        tiles: np.ndarray | None = None,
        tile_type: np.ndarray | None = None,
    ):
        """Draw the pool's tiles from ``config.seed``, or take given ``tiles`` (tiles, tile size) and their
        ``tile_type`` ids (e.g. hand-made terrain in tests)."""
        self.config, self.layout = config, layout
        if tiles is None:
            tiles, tile_type = _draw_tiles(config, layout)
        self.reach = None  # (tiles, n, n) path distances from the spawn, with terrain.reachability
        if config.reachability.enabled:
            tiles, self.reach = _reachable_tiles(config, layout, np.array(tiles, np.float32), tile_type)
        if len(tiles) != len(layout.slots()) or len(tile_type) != len(tiles):
            raise ValueError(
                f"a pool of this layout holds {len(layout.slots())} tiles, got {len(tiles)} "
                f"(and {len(tile_type)} type ids)"
            )
        self.tiles = np.asarray(tiles, np.float32)  # (tiles, tile nrow * ncol) in [0, 1]
        self.tile_type = np.asarray(tile_type, np.int32)  # (tiles,) index into TERRAIN_TYPES
        self.centres = layout.centres()
        self.atlas = layout.assemble(self.tiles)
        self.tile_level = layout.tile_level()
        first = np.cumsum((0,) + tuple(c * layout.levels for c in layout.counts[:-1]))
        self._first = jnp.asarray(first, jnp.int32)  # first tile of each type's row
        self._count = jnp.asarray(layout.counts, jnp.int32)  # tiles per level of each row
        self._random_row = jnp.asarray([t in RANDOM_TYPES for t in layout.types])
        self._log_p = jnp.log(jnp.asarray(np.asarray(config.proportions, np.float64) + 1e-30, jnp.float32))

    def draw(
        self, key: jax.Array, cell: jax.Array | None = None, half: jax.Array | None = None
    ) -> tuple[jax.Array, jax.Array]:
        """(tile index, type id) of one episode; ``cell`` = (type row, level) int32 (2,) picks the cell, a
        negative row draws type and level from the proportions (traced: one compiled draw for both);
        ``half`` (0 or 1, traced): a random type's tile among that half of its cell's tiles (the tiles of
        a cell at even or odd positions: ``hsa_mjx.terrain.regeneration``)."""
        if not self.config.per_env:
            return jnp.zeros((), jnp.int32), jnp.asarray(self.tile_type[0], jnp.int32)
        k_type, k_tile = jax.random.split(key)
        row = (
            jax.random.categorical(k_type, self._log_p).astype(jnp.int32)
            if len(self._log_p) > 1
            else jnp.zeros((), jnp.int32)
        )
        level = (
            jax.random.randint(jax.random.fold_in(k_type, 1), (), 0, self.layout.levels)
            if self.layout.levels > 1
            else jnp.zeros((), jnp.int32)
        )
        if cell is not None:
            free = cell[0] < 0
            row, level = jnp.where(free, row, cell[0]), jnp.where(free, level, cell[1])
        return self._tile(k_tile, row, level, half)

    def _tile(
        self, key: jax.Array, row: jax.Array, level: jax.Array, half: jax.Array | None = None
    ) -> tuple[jax.Array, jax.Array]:
        """A random tile of the cell (row, level) (of ``half`` of it, for a random type) and its type id."""
        count = self._count[row]
        if half is None:
            index = jax.random.randint(key, (), 0, count)
        else:
            alternate = self._random_row[row] & (count >= 2)
            index = jax.random.randint(key, (), 0, jnp.where(alternate, (count - half + 1) // 2, count))
            index = jnp.where(alternate, half + 2 * index, index)
        tile = self._first[row] + level * count + index
        return tile, jnp.asarray(self.tile_type)[tile]


def _tile_keys(config: TerrainConfig, layout: AtlasLayout, row: int) -> jax.Array:
    """The keys of a row's tiles, level by level (each random tile drawn from its own)."""
    row_key = jax.random.fold_in(jax.random.PRNGKey(config.seed), row)
    return jax.random.split(row_key, layout.counts[row] * layout.levels)


def _reachable_tiles(
    config: TerrainConfig, layout: AtlasLayout, tiles: np.ndarray, tile_type: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The tiles with every random one re-drawn (a new key per attempt) while it holds less reachable goal
    ground than ``terrain.reachability`` asks, and their path-distance fields; ValueError naming the tiles
    that still fail (deterministic types cannot be re-drawn)."""
    reach = config.reachability
    limits = dataclasses.replace(traversability.ROBOT, resolution=reach.resolution)
    fields = reachability.spawn_fields(tiles, layout.tile, limits)
    sampler = TerrainSampler(config, layout.tile)
    slots, level = layout.slots(), layout.tile_level()
    first = np.cumsum((0,) + tuple(c * layout.levels for c in layout.counts[:-1]))
    keys = {row: _tile_keys(config, layout, row) for row in range(layout.rows)}
    for attempt in range(1, reach.redraws + 1):
        failing = np.flatnonzero(reachability.goal_area(fields, reach.goal_range, reach.resolution) < reach.min_area)
        failing = [i for i in failing if layout.types[slots[i][0]] in RANDOM_TYPES]
        if not failing:
            break
        for i in failing:
            row = slots[i][0]
            key = jax.random.fold_in(keys[row][i - first[row]], attempt)
            tiles[i] = np.asarray(sampler.type_data(row, key, layout.difficulties[level[i]]))
        fields[failing] = reachability.spawn_fields(tiles[failing], layout.tile, limits)
    area = reachability.goal_area(fields, reach.goal_range, reach.resolution)
    bad = [f"{TERRAIN_TYPES[tile_type[i]]} level {level[i]}" for i in np.flatnonzero(area < reach.min_area)]
    if bad:
        raise ValueError(
            f"terrain tiles with less than terrain.reachability.min_area = {reach.min_area} m^2 of reachable ground "
            f"at path distances {tuple(reach.goal_range)} m after {reach.redraws} re-draws: {bad}; lower the "
            "difficulty of these types or change their parameters"
        )
    return tiles, fields


def _draw_tiles(config: TerrainConfig, layout: AtlasLayout) -> tuple[np.ndarray, np.ndarray]:
    """Every tile of the pool: one shared terrain, or row by row each random tile from its own key."""
    sampler = TerrainSampler(config, layout.tile)
    if not config.per_env:
        data, type_id = jax.jit(sampler.sample)(jax.random.PRNGKey(config.seed))
        return np.asarray(data)[None], np.asarray([int(type_id)], np.int32)
    tiles, types = [], []
    difficulty = np.asarray(layout.difficulties, np.float32)
    for row, (name, count) in enumerate(zip(layout.types, layout.counts)):
        keys = _tile_keys(config, layout, row)
        per_tile = jnp.asarray(np.repeat(difficulty, count))  # level by level
        data = jax.jit(jax.vmap(lambda k, d, r=row: sampler.type_data(r, k, d)))(keys, per_tile)
        tiles.append(np.asarray(data))
        types += [TERRAIN_TYPES.index(name)] * (count * layout.levels)
    return np.concatenate(tiles), np.asarray(types, np.int32)

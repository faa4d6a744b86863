"""The ground the robot reaches from its spawn on each tile, and goals drawn on it at a path distance.

:func:`spawn_fields` maps every tile of a pool at once: its surface, the cells the robot cannot enter
(``traversability.ROBOT``: steps, slopes, grown by the half-width) and the path distance from the spawn
(the tile's origin) to every other cell, ``inf`` where no path leads. :func:`goal_area` is the reachable
ground at path distances inside a range; the atlas re-draws tiles with too little of it.
:func:`reachable_goal` draws a goal uniformly over the cells of a tile whose path distance lies in the
requested range (inside the configured bearings), so no goal sits behind a wall, in a pole or beyond a
cliff. The same fields serve the tests.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.terrain import traversability as tv
from hsa_mjx.terrain.grid import Grid


def spawn_field(data: jax.Array, grid: Grid, limits: tv.Limits) -> jax.Array:
    """Path distance (m) from the tile's origin to each cell of its map, (n, n); ``inf`` where unreachable."""
    free = tv.free_cells(tv.surface_map(data, grid, limits.resolution), limits)
    origin = tv.cell_of(jnp.zeros(2), grid, limits.resolution)
    return tv.path_distances(free.at[origin[0], origin[1]].set(True), origin, limits.resolution)


def spawn_fields(tiles: np.ndarray, grid: Grid, limits: tv.Limits) -> np.ndarray:
    """:func:`spawn_field` of every tile, (tiles, n, n) float32 (one vmapped relaxation)."""
    fields = jax.jit(jax.vmap(lambda d: spawn_field(d, grid, limits)))(jnp.asarray(tiles, jnp.float32))
    return np.array(fields, np.float32)  # a writable copy: the atlas replaces re-drawn tiles in it


def goal_area(fields: np.ndarray, goal_range: tuple[float, float], resolution: float) -> np.ndarray:
    """Reachable ground (m^2) at a path distance inside ``goal_range`` on each tile, (tiles,)."""
    lo, hi = goal_range
    return ((fields >= lo) & (fields <= hi)).sum(axis=(-2, -1)) * resolution**2


def cell_centres(grid: Grid, resolution: float) -> np.ndarray:
    """Tile coordinates (x, y) of every map cell, (n, n, 2) (``traversability.map_points``)."""
    return tv.map_points(grid, resolution)


def bearing_mask(centres: np.ndarray, bearing_deg: tuple[float, float]) -> np.ndarray:
    """Cells whose bearing from +x lies in ``bearing_deg`` = (lo, hi) degrees, either side, (n, n) bool."""
    bearing = np.degrees(np.abs(np.arctan2(centres[..., 1], centres[..., 0])))
    return (bearing >= bearing_deg[0]) & (bearing <= bearing_deg[1])


def reachable_goal(
    key: jax.Array,
    field: jax.Array,
    centres: jax.Array,
    allowed: jax.Array,
    goal_range: jax.Array,
    fallback: jax.Array,
) -> jax.Array:
    """A goal (x, y) drawn uniformly over the ``allowed`` cells (e.g. :func:`bearing_mask`) of ``field`` whose
    path distance lies in ``goal_range`` (traced), jittered inside its cell; ``fallback`` when no cell
    qualifies (the atlas check keeps that off the configured range)."""
    ok = allowed & (field >= goal_range[0]) & (field <= goal_range[1])
    k_cell, k_jitter = jax.random.split(key)
    cell = jax.random.categorical(k_cell, jnp.where(ok, 0.0, -jnp.inf).reshape(-1))
    spacing = centres[0, 1, 0] - centres[0, 0, 0]
    jitter = jax.random.uniform(k_jitter, (2,), minval=-0.45, maxval=0.45) * spacing
    return jnp.where(jnp.any(ok), centres.reshape(-1, 2)[cell] + jitter, fallback)

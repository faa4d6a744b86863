"""Distance to the goal along the ground: fields precomputed for a set of goal sites on every tile.

A geodesic progress reward needs, at every step of every env, the path distance from the robot to its
goal. Computing a field per goal at reset is out of reach (the batch resets every env's state each step
and selects; a relaxation over the map per env per step would cost more than the physics), so each tile
gets ``count`` **goal sites** when the atlas is built, and one distance field per site:

- :func:`pick_sites` spreads the sites over the reachable ground evenly in path distance from the spawn
  (site k in the k-th of ``count`` equal bins of the goal range), so any sub-range the goal curriculum
  asks for holds its share of them;
- :func:`site_field` is the path distance to the site over the robot's free cells
  (``traversability.free_cells``), then carried into the cells the robot's centre cannot occupy (next to a
  pole, on a wall) by the shortest straight continuation (:func:`extend`), so the robot gets a finite,
  continuous distance wherever it is;
- :func:`field_distance` reads a field at any point (bilinear), :func:`path_direction` its downhill
  direction (the way the path leaves the point).

Fields are kept at every ``stride``-th cell of the traversability map (0.2 m for the default 0.1 m map
and stride 2) as float32: ``tiles x count x 51 x 51 x 4`` bytes (10 KB a site). The spiral task's sites
are its checkpoints (:func:`fixed_sites`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.terrain import traversability as tv
from hsa_mjx.terrain.grid import Grid


@dataclasses.dataclass(frozen=True)
class GoalSites:
    """Every tile's goal sites and their distance fields (numpy on the host, device arrays in the env).

    Args:
        xy: site positions in tile coordinates, (tiles, count, 2).
        spawn_distance: path distance from the spawn to each site, (tiles, count).
        fields: path distance to each site on the field grid, (tiles, count, m, m) float32.
        origin: tile coordinates (x, y) of field cell (0, 0).
        spacing: the field grid's cell size (m).
    """

    xy: np.ndarray
    spawn_distance: np.ndarray
    fields: np.ndarray
    origin: tuple[float, float]
    spacing: float

    @property
    def nbytes(self) -> int:
        """Memory of the fields."""
        return int(self.fields.nbytes)


def extend(distances: jax.Array, resolution: float) -> jax.Array:
    """``distances`` with every ``inf`` cell given the shortest 8-connected continuation from a finite one
    (finite cells keep their value), (n, n)."""
    return tv.relax(distances, ~jnp.isfinite(distances), resolution)


def site_field(free: jax.Array, site: jax.Array, resolution: float) -> jax.Array:
    """Path distance (m) to the map cell ``site`` (row, col) over ``free`` cells, extended to the others."""
    free = free.at[site[0], site[1]].set(True)
    return extend(tv.path_distances(free, site, resolution), resolution)


def pick_sites(key: jax.Array, spawn_field: jax.Array, goal_range: tuple[float, float], count: int) -> jax.Array:
    """``count`` map cells (row, col), (count, 2) int32: site k drawn uniformly among the cells whose path
    distance from the spawn lies in the k-th of ``count`` equal bins of ``goal_range`` (among all cells in
    the range when its bin is empty; the spawn's own cell when none is, which the atlas check prevents)."""
    lo, hi = goal_range
    width = (hi - lo) / count
    n = spawn_field.shape[1]
    flat = spawn_field.reshape(-1)
    in_range = (flat >= lo) & (flat <= hi)
    spawn = jnp.argmin(flat)

    def one(k, bin_key):
        in_bin = (flat >= lo + k * width) & (flat <= lo + (k + 1) * width)
        ok = jnp.where(jnp.any(in_bin), in_bin, in_range)
        cell = jax.random.categorical(bin_key, jnp.where(ok, 0.0, -jnp.inf))
        cell = jnp.where(jnp.any(ok), cell, spawn)
        return jnp.stack([cell // n, cell % n]).astype(jnp.int32)

    return jax.vmap(one)(jnp.arange(count), jax.random.split(key, count))


def fixed_sites(points: np.ndarray, grid: Grid, resolution: float) -> jax.Array:
    """The map cells (row, col) holding given points (e.g. the spiral's checkpoints), (count, 2) int32."""
    return tv.cell_of(jnp.asarray(points, jnp.float32), grid, resolution)


@dataclasses.dataclass(frozen=True)
class SiteSpec:
    """How a pool's goal sites are laid out: the tile ``grid``, the robot's ``limits`` (their map resolution),
    the ``goal_range`` the sites spread over, ``count`` sites a tile, fields kept at every ``stride``-th cell."""

    grid: Grid
    limits: tv.Limits
    goal_range: tuple[float, float]
    count: int
    stride: int


def tile_sites(
    spec: SiteSpec, data: jax.Array, spawn_field: jax.Array, key: jax.Array, cells: jax.Array | None = None
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """One tile's sites: (xy (count, 2), spawn distance (count,), fields (count, m, m) at every
    ``stride``-th cell); ``cells`` fixes the sites' map cells instead of :func:`pick_sites`."""
    res = spec.limits.resolution
    free = tv.free_cells(tv.surface_map(data, spec.grid, res), spec.limits)
    if cells is None:
        cells = pick_sites(key, spawn_field, spec.goal_range, spec.count)
    fields = jax.vmap(lambda c: site_field(free, c, res))(cells)
    points = jnp.asarray(tv.map_points(spec.grid, res))
    every = spec.stride
    return points[cells[:, 0], cells[:, 1]], spawn_field[cells[:, 0], cells[:, 1]], fields[:, ::every, ::every]


def build(
    spec: SiteSpec, tiles: np.ndarray, spawn_fields: np.ndarray, key: jax.Array, points: np.ndarray | None = None
) -> GoalSites:
    """Goal sites and fields of every tile (one jitted, vmapped pass; tile i draws from ``fold_in(key, i)``);
    ``points`` (count, 2) puts the same sites on every tile (the spiral's checkpoints)."""
    cells = None if points is None else fixed_sites(points, spec.grid, spec.limits.resolution)

    def one(data, field, index):
        return tile_sites(spec, data, field, jax.random.fold_in(key, index), cells)

    index = jnp.arange(len(tiles))
    xy, spawn, fields = jax.jit(jax.vmap(one))(jnp.asarray(tiles), jnp.asarray(spawn_fields), index)
    origin = tuple(float(v) for v in tv.map_points(spec.grid, spec.limits.resolution)[0, 0])
    spacing = spec.limits.resolution * spec.stride
    return GoalSites(np.asarray(xy), np.asarray(spawn), np.asarray(fields, np.float32), origin, spacing)


def field_distance(field: jax.Array, origin: tuple[float, float], spacing: float, xy: jax.Array) -> jax.Array:
    """The field read at point ``xy`` (2,) by bilinear interpolation (clamped to the grid), ()."""
    m = field.shape[0]
    u = jnp.clip((xy[0] - origin[0]) / spacing, 0.0, m - 1.0)
    v = jnp.clip((xy[1] - origin[1]) / spacing, 0.0, m - 1.0)
    c0, r0 = jnp.minimum(jnp.floor(u), m - 2).astype(jnp.int32), jnp.minimum(jnp.floor(v), m - 2).astype(jnp.int32)
    fu, fv = u - c0, v - r0
    top = field[r0, c0] * (1 - fu) + field[r0, c0 + 1] * fu
    bottom = field[r0 + 1, c0] * (1 - fu) + field[r0 + 1, c0 + 1] * fu
    return top * (1 - fv) + bottom * fv


def path_direction(field: jax.Array, origin: tuple[float, float], spacing: float, xy: jax.Array) -> jax.Array:
    """Unit vector (2,) down the field at ``xy`` (central differences half a cell either side); zeros
    where the field is flat there (at the site)."""
    h = 0.5 * spacing
    grad = jnp.stack(
        [
            field_distance(field, origin, spacing, xy + jnp.array([h, 0.0]))
            - field_distance(field, origin, spacing, xy - jnp.array([h, 0.0])),
            field_distance(field, origin, spacing, xy + jnp.array([0.0, h]))
            - field_distance(field, origin, spacing, xy - jnp.array([0.0, h])),
        ]
    )
    norm = jnp.linalg.norm(grad)
    return jnp.where(norm > 1e-6, -grad / jnp.maximum(norm, 1e-6), 0.0)

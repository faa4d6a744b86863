"""Where on a terrain tile the robot can go, and how far it is to a point along the ground (pure JAX).

A tile's surface is sampled on a square map of ``resolution`` cells (:func:`surface_map`, MuJoCo's own
triangulation). A cell is **blocked** where the robot cannot stand or cross: a height step to a
neighbouring cell above ``max_step`` (a wall, a pole's side) or a slope above ``max_slope`` measured over
the robot's length. Blocked cells are grown by the robot's half-width, so a gap narrower than the robot
closes and the robot's centre may use every free cell. :func:`path_distances` is the length of the
shortest 8-connected path over free cells from every cell to a target (a geodesic distance field,
computed by relaxation on the device); cells it cannot reach are ``inf``. The same functions serve a
goal sampler (goals on reachable cells at a path distance), a progress reward along the path and the
tests; the limits themselves are the robot's (:class:`Limits`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.terrain.grid import Grid, surface_height

NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1))


@dataclasses.dataclass(frozen=True)
class Limits:
    """What the robot passes: every value in metres but the slope (rise over run).

    Args:
        max_step: the highest height difference between neighbouring cells it crosses.
        max_slope: the steepest slope it climbs.
        half_width: half its width: blocked cells grow by this much.
        resolution: the map's cell size.
    """

    max_step: float
    max_slope: float
    half_width: float
    resolution: float = 0.05

    def __post_init__(self) -> None:
        for name in ("max_step", "max_slope", "half_width", "resolution"):
            if not getattr(self, name) > 0:
                raise ValueError(f"traversability limit '{name}' must be > 0, got {getattr(self, name)!r}")


def surface_map(data: jax.Array, grid: Grid, resolution: float) -> jax.Array:
    """The tile's surface heights on a square map of ``resolution`` cells, (n, n), rows along world y."""
    count = int(np.floor(2 * grid.half_x / resolution)) + 1
    xs = -grid.half_x + resolution * jnp.arange(count)
    ys = -grid.half_y + resolution * jnp.arange(count)
    xy = jnp.stack(jnp.meshgrid(xs, ys), axis=-1)
    return surface_height(data, grid, xy)


def _shifted(a: jax.Array, dr: int, dc: int, fill: float) -> jax.Array:
    """``a`` moved so that out[r, c] = a[r + dr, c + dc], ``fill`` outside."""
    padded = jnp.pad(a, 1, constant_values=fill)
    n, m = a.shape
    return padded[1 + dr : 1 + dr + n, 1 + dc : 1 + dc + m]


def blocked(heights: jax.Array, limits: Limits) -> jax.Array:
    """Cells the robot cannot enter, before growing: a step to a 4-neighbour above ``max_step``, or a
    local slope (central differences over the neighbouring cells) above ``max_slope``, (n, n) bool."""
    step = jnp.zeros(heights.shape, heights.dtype)
    for dr, dc in NEIGHBOURS[:4]:
        neighbour = _shifted(heights, dr, dc, jnp.nan)
        step = jnp.maximum(step, jnp.nan_to_num(jnp.abs(neighbour - heights), nan=0.0))
    rise_y, rise_x = jnp.gradient(heights, limits.resolution)  # one-sided at the map's edges
    return (step > limits.max_step) | (jnp.hypot(rise_x, rise_y) > limits.max_slope)


def grown(mask: jax.Array, radius: float, resolution: float) -> jax.Array:
    """``mask`` dilated by a disc of ``radius`` metres (a cell is set when any set cell lies within it)."""
    r = int(np.ceil(radius / resolution))
    offsets = [
        (i, j) for i in range(-r, r + 1) for j in range(-r, r + 1) if (i * i + j * j) * resolution**2 <= radius**2
    ]
    padded = jnp.pad(mask, r, constant_values=False)
    n, m = mask.shape
    out = jnp.zeros_like(mask)
    for i, j in offsets:
        out = out | padded[r + i : r + i + n, r + j : r + j + m]
    return out


def free_cells(heights: jax.Array, limits: Limits) -> jax.Array:
    """Where the robot's centre may be: not within ``half_width`` of a blocked cell, (n, n) bool."""
    return jnp.logical_not(grown(blocked(heights, limits), limits.half_width, limits.resolution))


def path_distances(free: jax.Array, target: tuple[int, int] | jax.Array, resolution: float) -> jax.Array:
    """Length in metres of the shortest 8-connected path over ``free`` cells from each cell to ``target``
    (row, col), (n, n) float32; ``inf`` where no path leads (or the target is not free)."""
    target = jnp.asarray(target, jnp.int32)
    start = jnp.full(free.shape, jnp.inf, jnp.float32).at[target[0], target[1]].set(0.0)
    start = jnp.where(free, start, jnp.inf)
    costs = [resolution * float(np.hypot(dr, dc)) for dr, dc in NEIGHBOURS]

    def relax(state):
        d, _ = state
        best = d
        for (dr, dc), cost in zip(NEIGHBOURS, costs):
            best = jnp.minimum(best, _shifted(d, dr, dc, jnp.inf) + cost)
        best = jnp.where(free, best, jnp.inf)
        return best, jnp.any(best < d)

    distances, _ = jax.lax.while_loop(lambda s: s[1], relax, (start, jnp.asarray(True)))
    return distances


def cell_of(xy: jax.Array, grid: Grid, resolution: float) -> jax.Array:
    """The map cell (row, col) holding world point ``xy`` (tile coordinates), int32."""
    col = jnp.round((xy[..., 0] + grid.half_x) / resolution)
    row = jnp.round((xy[..., 1] + grid.half_y) / resolution)
    return jnp.stack([row, col], axis=-1).astype(jnp.int32)

"""Where on a terrain tile the robot can go, and how far it is to a point along the ground (pure JAX).

A tile's surface is sampled on a square map of ``resolution`` cells (:func:`surface_map`, MuJoCo's own
triangulation). Two things stop the robot (:func:`blocked`): a **wall**, where the local slope is steeper
than a rise of ``max_step`` over ``step_run`` (a pole's side, a corridor wall, a step it cannot climb: the
heightfield draws a step as a rise over one vertex spacing), and **steep ground**, a slope above
``max_slope`` measured over ``slope_span`` (the robot's length: it bridges a short rise it could not
climb as a long slope). Walls are grown by the robot's half-width, so a gap narrower than the robot
closes and the robot's centre may use every free cell; steep ground is not (its span already holds the
robot). :func:`path_distances` is the length of the shortest 8-connected path over free cells from every
cell to a target (a geodesic distance field, computed by relaxation sweeps on the device); cells it cannot reach
are ``inf``. The same functions serve the goal sampler (``hsa_mjx.terrain.reachability``), the atlas and
the tests. :data:`ROBOT` holds this robot's limits as ``python -m benchmarks.terrain.capability`` measured them
(``docs/terrain.md``).
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
        max_step: the highest step it climbs, as a rise over ``step_run``: steeper ground is a wall.
        max_slope: the steepest slope it climbs.
        half_width: half its width: blocked cells grow by this much.
        resolution: the map's cell size.
        slope_span: the run over which a slope is measured (at least two cells: central differences).
        step_run: the run of a step (the heightfield's vertex spacing, 10 m / 49).
    """

    max_step: float
    max_slope: float
    half_width: float
    resolution: float = 0.05
    slope_span: float = 0.1
    step_run: float = 10.0 / 49.0

    def __post_init__(self) -> None:
        for name in ("max_step", "max_slope", "half_width", "resolution", "slope_span", "step_run"):
            if not getattr(self, name) > 0:
                raise ValueError(f"traversability limit '{name}' must be > 0, got {getattr(self, name)!r}")


# This robot's limits, measured by ``python -m benchmarks.terrain.capability`` (docs/terrain.md): a 5 cm step (a
# rise over one heightfield vertex spacing) passes, 7.5 cm does not; an incline of 8 degrees passes, 12 does
# not (over the robot's 0.46 m length: 0.141 passes, 0.213 fails); half its 0.28 m full width (blocks
# 0.24 m, the HSA units 0.28 m).
ROBOT = Limits(max_step=0.05, max_slope=0.141, half_width=0.14, resolution=0.1, slope_span=0.46)


def map_points(grid: Grid, resolution: float) -> np.ndarray:
    """Tile coordinates (x, y) of every cell of the square map of ``resolution`` cells, (n, n, 2) float32,
    rows along world y."""
    count = int(np.floor(2 * grid.half_x / resolution)) + 1
    xs = -grid.half_x + resolution * np.arange(count)
    ys = -grid.half_y + resolution * np.arange(count)
    return np.stack(np.meshgrid(xs, ys), axis=-1).astype(np.float32)


def surface_map(data: jax.Array, grid: Grid, resolution: float) -> jax.Array:
    """The tile's surface heights on the map of ``resolution`` cells (:func:`map_points`), (n, n)."""
    return surface_height(data, grid, jnp.asarray(map_points(grid, resolution)))


def shifted(a: jax.Array, dr: int, dc: int, fill: float) -> jax.Array:
    """``a`` moved so that out[r, c] = a[r + dr, c + dc], ``fill`` outside."""
    padded = jnp.pad(a, 1, constant_values=fill)
    n, m = a.shape
    return padded[1 + dr : 1 + dr + n, 1 + dc : 1 + dc + m]


def walls(heights: jax.Array, limits: Limits) -> jax.Array:
    """Cells whose local slope (over the neighbouring cells) is steeper than ``max_step / step_run``, (n, n)."""
    rise_y, rise_x = (_rise(heights, axis, 1, limits.resolution) for axis in (0, 1))
    return jnp.hypot(rise_x, rise_y) > limits.max_step / limits.step_run


def span_slope(heights: jax.Array, limits: Limits) -> jax.Array:
    """The slope (rise over run) over ``slope_span`` at each cell: each axis between the cells half a span
    before and after (clipped to the map), (n, n)."""
    k = max(1, int(round(0.5 * limits.slope_span / limits.resolution)))
    rise_y, rise_x = (_rise(heights, axis, k, limits.resolution) for axis in (0, 1))
    return jnp.hypot(rise_x, rise_y)


def steep(heights: jax.Array, limits: Limits) -> jax.Array:
    """Cells where :func:`span_slope` is above ``max_slope``, (n, n) bool."""
    return span_slope(heights, limits) > limits.max_slope


def blocked(heights: jax.Array, limits: Limits) -> jax.Array:
    """Cells the robot cannot enter, before growing: :func:`walls` or :func:`steep`, (n, n) bool."""
    return walls(heights, limits) | steep(heights, limits)


def _rise(heights: jax.Array, axis: int, k: int, resolution: float) -> jax.Array:
    """Rise per metre along ``axis`` between the cells ``k`` before and ``k`` after each cell (clipped to
    the map, over the run that remains there)."""
    n = heights.shape[axis]
    index = np.arange(n)
    lo, hi = np.maximum(index - k, 0), np.minimum(index + k, n - 1)
    run = ((hi - lo) * resolution).reshape([-1 if a == axis else 1 for a in range(heights.ndim)])
    return (jnp.take(heights, hi, axis=axis) - jnp.take(heights, lo, axis=axis)) / run


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
    """Where the robot's centre may be: not within ``half_width`` of a wall, not on steep ground, (n, n) bool."""
    near_wall = grown(walls(heights, limits), limits.half_width, limits.resolution)
    return jnp.logical_not(near_wall | steep(heights, limits))


def path_distances(free: jax.Array, target: tuple[int, int] | jax.Array, resolution: float) -> jax.Array:
    """Length in metres of the shortest 8-connected path over ``free`` cells from each cell to ``target``
    (row, col), (n, n) float32; ``inf`` where no path leads (or the target is not free)."""
    target = jnp.asarray(target, jnp.int32)
    start = jnp.full(free.shape, jnp.inf, jnp.float32).at[target[0], target[1]].set(0.0)
    return relax(jnp.where(free, start, jnp.inf), free, resolution)


def relax(distances: jax.Array, update: jax.Array, resolution: float) -> jax.Array:
    """The fixed point of ``d = min(d, d[neighbour] + step)`` over the 8 neighbours (step: ``resolution``,
    or its diagonal), each ``update`` cell taking it and the others keeping their value, (n, n).

    Why sweeps: four Gauss-Seidel sweeps (down, up, right, left; each cell from the three cells of the row
    before it, already swept) carry a distance along a whole straight or diagonal run in one pass, so it
    converges in a few passes where a Jacobi step (every cell from its neighbours at once) takes one pass
    per cell of the longest path. Each distance is still a sum of steps in path order and every cell ends
    at the minimum over its neighbours, so the field is the same, bit for bit, as the Jacobi iteration's."""
    update = jnp.asarray(update, bool)

    def passes(state: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        d, _ = state
        new = d
        for transposed in (False, True):
            for reverse in (False, True):
                new = _sweep(new, update, resolution, transposed, reverse)
        return new, jnp.any(new < d)

    out, _ = jax.lax.while_loop(lambda s: s[1], passes, (distances, jnp.asarray(True)))
    return out


def _sweep(d: jax.Array, update: jax.Array, resolution: float, transposed: bool, reverse: bool) -> jax.Array:
    """One Gauss-Seidel pass of :func:`relax` over the rows (``transposed``: the columns), in order or
    ``reverse``d: each row from the row before it in the pass, already updated."""
    straight, diagonal = (resolution * float(np.hypot(1, k)) for k in (0, 1))
    if transposed:
        d, update = d.T, update.T

    def row(before: jax.Array, current: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        values, ok = current
        side = jnp.minimum(_moved(before, 1), _moved(before, -1))
        best = jnp.minimum(jnp.minimum(values, before + straight), side + diagonal)
        best = jnp.where(ok, best, values)
        return best, best

    _, out = jax.lax.scan(row, jnp.full(d.shape[1:], jnp.inf, d.dtype), (d, update), reverse=reverse)
    return out.T if transposed else out


def _moved(v: jax.Array, k: int) -> jax.Array:
    """``v`` moved so that out[i] = v[i + k] (k = +-1), ``inf`` outside."""
    fill = jnp.full((1,), jnp.inf, v.dtype)
    return jnp.concatenate([v[1:], fill]) if k > 0 else jnp.concatenate([fill, v[:-1]])


def cell_of(xy: jax.Array, grid: Grid, resolution: float) -> jax.Array:
    """The map cell (row, col) holding world point ``xy`` (tile coordinates), int32."""
    col = jnp.round((xy[..., 0] + grid.half_x) / resolution)
    row = jnp.round((xy[..., 1] + grid.half_y) / resolution)
    return jnp.stack([row, col], axis=-1).astype(jnp.int32)

"""The eleven terrain generators of the original as pure JAX functions of world coordinates.

Every generator has the signature ``fn(key, params, grid, x, y, difficulty=1.0) -> heights``
where ``x``, ``y`` are world coordinates (metres) of any common shape, ``params`` its frozen
parameter dataclass (static) and ``grid`` the static :class:`~hsa_mjx.terrain.grid.Grid` (vertex
spacing, field size); the result has the shape of ``x`` and holds world heights in metres above
the generator's reference level 0 (negative values are allowed;
:func:`~hsa_mjx.terrain.grid.to_hfield_data` lifts them). Random draws depend on the key only,
never on the shape of ``x``, so evaluating a generator on the vertex mesh or at a single point
gives the same terrain.

``difficulty`` in [0, 1] (a float or a traced scalar) scales the one parameter that makes each
type hard, from 0 (level ground) to the configured value at 1: the wave, noise, step, crater,
pole and wall heights, the ramp's height and the inclines' angle (``DIFFICULTY_PARAMETER``).
Positions and sizes (where the craters and poles are, the tracks' layout) do not change with it.

Sharp edges (stairs, corridor and spiral walls) are drawn as a linear ramp one vertex spacing
wide centred on the requested position, so the edge sits where it was asked for at half height
whatever the grid alignment (the original snapped them to the 0.2 m cell it assumed).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.terrain import noise
from hsa_mjx.terrain.grid import Grid
from hsa_mjx.terrain.params import (
    CorridorParams,
    CratersParams,
    FlatWithInclineParams,
    FlatWithRampParams,
    InclineParams,
    PerlinParams,
    PolesParams,
    SpiralParams,
    StairsParams,
    WavyParams,
)

Generator = Callable[..., jax.Array]  # (key, params, grid, x, y, difficulty=1.0) -> heights
Difficulty = float | jax.Array


def soft_edge(distance: jax.Array, edge: float, ramp: float) -> jax.Array:
    """0 below ``edge - ramp / 2``, 1 above ``edge + ramp / 2``, linear in between."""
    return jnp.clip((distance - edge) / ramp + 0.5, 0.0, 1.0)


def _slope_coordinate(x: jax.Array, y: jax.Array, direction: str) -> jax.Array:
    """Distance along an incline direction: x, y, or the (x + y) / sqrt(2) diagonal."""
    if direction == "x":
        return x
    if direction == "y":
        return y
    return (x + y) / math.sqrt(2.0)


def _slope(angle: float, difficulty: Difficulty) -> jax.Array | float:
    """tan of ``difficulty x angle`` degrees (a Python float when the difficulty is one)."""
    if isinstance(difficulty, (int, float)):
        return math.tan(math.radians(angle * difficulty))
    return jnp.tan(jnp.radians(angle * difficulty))


def _random_vertices(key: jax.Array, count: int, grid: Grid) -> tuple[jax.Array, jax.Array]:
    """World (x, y) of ``count`` uniformly drawn vertices (the original drew integer cells)."""
    k_col, k_row = jax.random.split(key)
    col = jax.random.randint(k_col, (count,), 0, grid.ncol)
    row = jax.random.randint(k_row, (count,), 0, grid.nrow)
    return -grid.half_x + col * grid.spacing_x, -grid.half_y + row * grid.spacing_y


def _pairwise_distance(x: jax.Array, y: jax.Array, cx: jax.Array, cy: jax.Array) -> jax.Array:
    """Distance from every point (shape S) to every centre (K,), shape S + (K,)."""
    return jnp.hypot(x[..., None] - cx, y[..., None] - cy)


def wavy(
    key: jax.Array, p: WavyParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """amplitude * sin(scale x) * cos(scale y): 0 at the spawn point."""
    return difficulty * p.amplitude * jnp.sin(p.scale * x) * jnp.cos(p.scale * y)


def perlin(
    key: jax.Array, p: PerlinParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """Fractal Perlin noise scaled by ``amplitude``; a new field for every key, 0 at the origin."""
    extent = max(grid.half_x, grid.half_y)
    field = noise.fractal_noise(key, x, y, p.scale, p.octaves, p.persistence, p.lacunarity, extent)
    return difficulty * p.amplitude * field


def stairs(
    key: jax.Array, p: StairsParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """Steps of ``step_height`` every ``step_length`` along +x; step 0 covers |x| < step_length / 2."""
    s = x / p.step_length + 0.5  # step boundaries at integer s
    ramp = min(grid.spacing_x / p.step_length, 1.0)
    nearest = jnp.round(s)
    return difficulty * p.step_height * (nearest - 1.0 + soft_edge(s - nearest, 0.0, ramp))


def flat(key: jax.Array, p: Any, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0) -> jax.Array:
    """Level ground."""
    return jnp.zeros(jnp.broadcast_shapes(jnp.shape(x), jnp.shape(y)), jnp.float32)


def incline(
    key: jax.Array, p: InclineParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """A plane through the spawn point rising at ``difficulty x angle`` degrees along ``direction``."""
    return _slope(p.angle, difficulty) * _slope_coordinate(x, y, p.direction)


def craters(
    key: jax.Array, p: CratersParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """``num`` Gaussian dips at random vertices, each cut off at its radius; overlaps add up."""
    if p.num == 0:
        return flat(key, p, grid, x, y)
    k_pos, k_radius, k_depth = jax.random.split(key, 3)
    cx, cy = _random_vertices(k_pos, p.num, grid)
    radius = jax.random.uniform(k_radius, (p.num,), minval=p.radius[0], maxval=p.radius[1])
    depth = jax.random.uniform(k_depth, (p.num,), minval=p.depth[0], maxval=p.depth[1])
    d = _pairwise_distance(x, y, cx, cy)
    dip = depth * jnp.exp(-(d**2) / (2.0 * (radius / 3.0) ** 2))
    return -difficulty * jnp.sum(jnp.where(d < radius, dip, 0.0), axis=-1)


def _spacing_offsets(grid: Grid, spacing: float) -> list[tuple[int, int]]:
    """Static (row, col) offsets of the vertices closer than ``spacing`` to a vertex (itself excluded)."""
    reach_r, reach_c = int(spacing / grid.spacing_y) + 1, int(spacing / grid.spacing_x) + 1
    return [
        (dr, dc)
        for dr in range(-reach_r, reach_r + 1)
        for dc in range(-reach_c, reach_c + 1)
        if (dr, dc) != (0, 0) and math.hypot(dr * grid.spacing_y, dc * grid.spacing_x) < spacing
    ]


def pole_centres(key: jax.Array, p: PolesParams, grid: Grid) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Up to ``num`` vertices, none closer than ``min_spacing`` to another: (x, y, present) of shape (num,).

    A parallel form of the original's sequential rejection sampling: every vertex far enough from
    the edge gets a random priority, a vertex is kept when it beats every vertex within
    ``min_spacing``, and the ``num`` kept vertices of highest priority become poles.
    """
    x, y = (jnp.asarray(a) for a in grid.mesh())
    r_max = p.radius[1]
    valid = (jnp.abs(x) <= grid.half_x - r_max) & (jnp.abs(y) <= grid.half_y - r_max)
    priority = jnp.where(valid, jax.random.uniform(key, (grid.nrow, grid.ncol)), -1.0)
    offsets = _spacing_offsets(grid, p.min_spacing)
    pad_r = max([abs(dr) for dr, _ in offsets], default=0)
    pad_c = max([abs(dc) for _, dc in offsets], default=0)
    padded = jnp.pad(priority, ((pad_r, pad_r), (pad_c, pad_c)), constant_values=-1.0)
    rival = jnp.full_like(priority, -1.0)
    for dr, dc in offsets:  # static neighbourhood, unrolled at trace time
        rival = jnp.maximum(rival, padded[pad_r + dr : pad_r + dr + grid.nrow, pad_c + dc : pad_c + dc + grid.ncol])
    score = jnp.where(valid & (priority > rival), priority, -1.0).reshape(-1)
    top, index = jax.lax.top_k(score, min(p.num, grid.size))
    return x.reshape(-1)[index], y.reshape(-1)[index], top >= 0.0


def poles(
    key: jax.Array, p: PolesParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """Poles of random radius and height: full height up to ``radius - edge``, linear to 0 at ``radius``.

    ``edge`` is one vertex spacing (or the radius if smaller), so the default 0.2 m poles are the
    original's single-vertex spikes. The difficulty scales their height (``grade: height``) or how many
    of the placed poles stand (``grade: count``: the ``ceil(difficulty x num)`` of highest priority, each
    at full height). No pole is taller than ``max_height``.
    """
    if p.num == 0:
        return flat(key, p, grid, x, y)
    k_pos, k_radius, k_height = jax.random.split(key, 3)
    cx, cy, present = pole_centres(k_pos, p, grid)
    count = cx.shape[0]
    scale = difficulty
    if p.grade == "count":
        present = present & (jnp.arange(count) < jnp.ceil(difficulty * p.num - 1e-6))
        scale = 1.0
    radius = jax.random.uniform(k_radius, (count,), minval=p.radius[0], maxval=p.radius[1])
    height = jax.random.uniform(k_height, (count,), minval=p.height[0], maxval=p.height[1])
    edge = jnp.minimum(radius, min(grid.spacing_x, grid.spacing_y))
    d = _pairwise_distance(x, y, cx, cy)
    profile = jnp.where(present, height * jnp.clip((radius - d) / edge, 0.0, 1.0), 0.0)
    return jnp.minimum(scale * jnp.max(profile, axis=-1), p.max_height)


def flat_with_incline(
    key: jax.Array, p: FlatWithInclineParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """Flat ground; inside the rectangle a slope (``difficulty x angle``) rising from 0 at its start edge,
    then a drop."""
    x0, x1 = (grid.fraction_to_x(f) for f in p.x_range)
    y0, y1 = (grid.fraction_to_y(f) for f in p.y_range)
    inside = (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
    rise = _slope(p.angle, difficulty) * _slope_coordinate(x - x0, y - y0, p.direction)
    return jnp.where(inside, rise, 0.0)


def flat_with_ramp(
    key: jax.Array, p: FlatWithRampParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """Flat ground with a ramp from 0 to ``difficulty x height`` over ``length``, optionally faded at its sides."""
    dx, dy = x - grid.fraction_to_x(p.center[0]), y - grid.fraction_to_y(p.center[1])
    along_x = p.direction.endswith("x")
    extent_along = 2.0 * (grid.half_x if along_x else grid.half_y)
    extent_across = 2.0 * (grid.half_y if along_x else grid.half_x)
    along, across = (dx, dy) if along_x else (dy, dx)
    along = -along if p.direction.startswith("-") else along
    length, half_width = p.length * extent_along, 0.5 * p.width * extent_across
    inside = (jnp.abs(along) < 0.5 * length) & (jnp.abs(across) < half_width)
    rise = difficulty * p.height * (along + 0.5 * length) / length
    if p.smooth_edges:
        q = jnp.abs(across) / half_width
        rise = rise * jnp.where(q > 0.7, jnp.maximum(0.0, 1.0 - (q - 0.7) / 0.3), 1.0)
    return jnp.where(inside, rise, 0.0)


def stage_fraction(difficulty: Difficulty, start: float, end: float) -> jax.Array:
    """How far ``difficulty`` has come from ``start`` to ``end``, in [0, 1] (1 from ``end`` on)."""
    if end <= start:
        return jnp.asarray(difficulty >= end, jnp.float32)
    return jnp.clip((jnp.asarray(difficulty, jnp.float32) - start) / (end - start), 0.0, 1.0)


def corridor(
    key: jax.Array, p: CorridorParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """Walls of ``wall_height`` on both sides of a floor running along ``axis``; the difficulty raises the
    walls, then narrows the floor, then bends it (``CorridorParams``)."""
    if p.axis == "x":
        along, lateral, ramp = x, y - grid.fraction_to_y(p.center), grid.spacing_y
    else:
        along, lateral, ramp = y, x - grid.fraction_to_x(p.center), grid.spacing_x
    width = p.corridor_width
    if p.start_width > 0:
        width = p.start_width + (p.corridor_width - p.start_width) * stage_fraction(
            difficulty, p.wall_until, p.width_until
        )
    if p.bend_amplitude > 0:
        amplitude = p.bend_amplitude * stage_fraction(difficulty, p.width_until, 1.0)
        phase = 2.0 * math.pi * along / p.bend_wavelength
        slope = amplitude * 2.0 * math.pi / p.bend_wavelength * jnp.cos(phase)
        lateral = (lateral - amplitude * jnp.sin(phase)) / jnp.sqrt(1.0 + slope**2)  # across the bent floor
    height = p.wall_height * jnp.minimum(1.0, jnp.asarray(difficulty, jnp.float32) / p.wall_until)
    return height * soft_edge(jnp.abs(lateral), 0.5 * width, ramp)


def spiral_track_distance(p: SpiralParams, x: jax.Array, y: jax.Array, extension: float) -> jax.Array:
    """Radial distance to the spiral centre line r(u) = r0 + (r1 - r0) u / (2 pi turns), at angle pi - u.

    ``u`` runs from 0 (angle pi, radius r0) clockwise to 2 pi turns (radius r1); the line is
    extended by ``extension`` radians at both ends so neither the first nor the last checkpoint
    sits against the track's end wall.
    """
    total = 2.0 * math.pi * p.turns
    r = jnp.hypot(x, y)
    u0 = jnp.mod(math.pi - jnp.arctan2(y, x), 2.0 * math.pi)
    laps = jnp.arange(-1, int((total + extension) // (2.0 * math.pi)) + 1, dtype=jnp.float32)
    u = u0[..., None] + 2.0 * math.pi * laps
    centre = jnp.maximum(p.start_radius + (p.end_radius - p.start_radius) * u / total, 0.0)
    on_track = (u >= -extension) & (u <= total + extension)
    return jnp.min(jnp.where(on_track, jnp.abs(r[..., None] - centre), jnp.inf), axis=-1)


def spiral_extension(p: SpiralParams) -> float:
    """How far (rad) the track runs past both ends of the line: about one track width."""
    return p.track_width / max(p.end_radius, p.track_width)


def spiral(
    key: jax.Array, p: SpiralParams, grid: Grid, x: jax.Array, y: jax.Array, difficulty: Difficulty = 1.0
) -> jax.Array:
    """Walls everywhere except the spiral track (the checkpoint path) and a start disc of radius r0."""
    ramp = max(grid.spacing_x, grid.spacing_y)
    track = soft_edge(spiral_track_distance(p, x, y, spiral_extension(p)), 0.5 * p.track_width, ramp)
    start = soft_edge(jnp.hypot(x, y), p.start_radius, ramp)
    return difficulty * p.wall_height * jnp.minimum(track, start)


# What difficulty scales in each type (its value at difficulty 1 is the configured one).
DIFFICULTY_PARAMETER: dict[str, str] = {
    "wavy": "amplitude",
    "perlin": "amplitude",
    "stairs": "step_height",
    "flat": "(none: always level)",
    "incline": "angle",
    "craters": "depth",
    "poles": "height (grade: height) or count (grade: count)",
    "flat_with_incline": "angle",
    "flat_with_ramp": "height",
    "corridor": "wall_height, then the width from start_width, then the bend",
    "spiral": "wall_height",
}

GENERATORS: dict[str, Generator] = {
    "wavy": wavy,
    "perlin": perlin,
    "stairs": stairs,
    "flat": flat,
    "incline": incline,
    "craters": craters,
    "poles": poles,
    "flat_with_incline": flat_with_incline,
    "flat_with_ramp": flat_with_ramp,
    "corridor": corridor,
    "spiral": spiral,
}


def vertex_mesh(grid: Grid) -> tuple[jax.Array, jax.Array]:
    """World (x, y) of the vertices as float32 constants, shape (nrow, ncol) each."""
    x, y = grid.mesh()
    return jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32)


def point_height(fn: Generator, params: Any, grid: Grid, x: float, y: float, difficulty: Difficulty = 1.0) -> jax.Array:
    """Height of a deterministic generator at one world point, shape () (traced with a traced difficulty)."""
    value = fn(
        jax.random.PRNGKey(0), params, grid, np.full((1,), x, np.float32), np.full((1,), y, np.float32), difficulty
    )
    return jnp.asarray(value, jnp.float32)[0]

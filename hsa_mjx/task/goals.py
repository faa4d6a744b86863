"""Goals held per env: fixed, the original's random rules, a radial range, or spiral checkpoints."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.config import EnvConfig, GoalConfig
from hsa_mjx.terrain.params import TERRAIN_TYPES, SpiralParams

FLAT_ID = TERRAIN_TYPES.index("flat")
FULL_CIRCLE = (0.0, 180.0)  # goal.radial_bearing_deg that means any direction


def spiral_checkpoints(goal: GoalConfig, path: SpiralParams = SpiralParams()) -> np.ndarray:
    """Checkpoints i = 1..N along the clockwise spiral of the original, shape (N, 2), on ``path``
    (``terrain.spiral``: the track's radii and turns).

    s = i / N, angle = pi - 2 pi turns s, radius = r0 + (r1 - r0) s.
    """
    s = np.arange(1, goal.num_checkpoints + 1) / goal.num_checkpoints
    angle = np.pi - 2.0 * np.pi * path.turns * s
    radius = path.start_radius + (path.end_radius - path.start_radius) * s
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1).astype(np.float32)


def _random_side(rng: jax.Array, low: float, high: float) -> jax.Array:
    k_side, k_mag = jax.random.split(rng)
    side = jnp.where(jax.random.bernoulli(k_side), 1.0, -1.0)
    return side * jax.random.uniform(k_mag, (), minval=low, maxval=high)


def original_random_goal(rng: jax.Array, terrain_type: str) -> jax.Array:
    """The original's rules: flat: x in +-[1.5, 4.5], y in [-4, 4]; else x in +-[1.5, 2.0], y = 0."""
    k_x, k_y = jax.random.split(rng)
    if terrain_type == "flat":
        return jnp.stack([_random_side(k_x, 1.5, 4.5), jax.random.uniform(k_y, (), minval=-4.0, maxval=4.0)])
    return jnp.stack([_random_side(k_x, 1.5, 2.0), jnp.zeros(())])


def random_goal(rng: jax.Array, types: tuple[str, ...], terrain_id: jax.Array | None) -> jax.Array:
    """The original's rules per env: the flat rule where the env's terrain is flat, the other elsewhere.

    ``terrain_id`` (traced, an index into ``TERRAIN_TYPES``) is needed only when ``types`` mixes
    flat with other terrain.
    """
    if all(t == "flat" for t in types):
        return original_random_goal(rng, "flat")
    if "flat" not in types:
        return original_random_goal(rng, types[0])
    if terrain_id is None:
        raise ValueError("a batch mixing flat and other terrain needs each env's terrain_id for its goal rule")
    return jnp.where(terrain_id == FLAT_ID, original_random_goal(rng, "flat"), original_random_goal(rng, "other"))


def radial_goal(rng: jax.Array, radius_range: jax.Array, bearing_deg: tuple[float, float] = FULL_CIRCLE) -> jax.Array:
    """Distance uniform in ``radius_range`` (traced); direction uniform in [0, 2 pi), or, with a
    static ``bearing_deg`` = (lo, hi), at lo..hi degrees from world +x (the spawn heading) on
    either side, each side equally likely."""
    k_r, k_a = jax.random.split(rng)
    radius = jax.random.uniform(k_r, (), minval=radius_range[0], maxval=radius_range[1])
    if tuple(bearing_deg) == FULL_CIRCLE:
        angle = jax.random.uniform(k_a, (), minval=0.0, maxval=2.0 * jnp.pi)
    else:
        angle = jnp.deg2rad(_random_side(k_a, float(bearing_deg[0]), float(bearing_deg[1])))
    return radius * jnp.stack([jnp.cos(angle), jnp.sin(angle)])


def initial_goal(
    rng: jax.Array,
    config: EnvConfig,
    radius_range: jax.Array,
    checkpoints: jax.Array,
    terrain_id: jax.Array | None = None,
) -> jax.Array:
    """The goal of a new episode; the mode is static, the ranges, checkpoints and terrain id traced."""
    mode = config.goal.mode
    if mode == "fixed":
        return jnp.asarray(config.goal.position, jnp.float32)
    if mode == "random":
        return random_goal(rng, config.terrain.types, terrain_id)
    if mode == "radial":
        return radial_goal(rng, radius_range, config.goal.radial_bearing_deg)
    return checkpoints[0]


def track_start(
    rng: jax.Array, checkpoints: jax.Array, max_index: int, origin: jax.Array, index: jax.Array | None = None
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A spiral episode's start along the track: (checkpoint index, robot xy, yaw).

    The index k is uniform in 0..``max_index`` (static), or ``index`` when given (``rng`` is then
    unused). k = 0 is the original start: ``origin`` (the spawn pose's position), yaw 0. For k > 0
    the robot stands on checkpoint k - 1, facing checkpoint k, which is its goal, as if it had
    just collected the ones before.
    """
    if index is None:
        index = jax.random.randint(rng, (), 0, max_index + 1)
    previous = checkpoints[jnp.maximum(index - 1, 0)]
    start = jnp.where(index > 0, previous, origin)
    ahead = checkpoints[index] - previous
    yaw = jnp.where(index > 0, jnp.arctan2(ahead[1], ahead[0]), 0.0)
    return index, start, yaw


def advance_checkpoint(
    position: jax.Array, checkpoints: jax.Array, index: jax.Array, radius: float
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Collect the current checkpoint if within ``radius``.

    Returns (collected, completed, new index); the index stops at N - 1 after the last one.
    """
    last = checkpoints.shape[0] - 1
    collected = jnp.linalg.norm(position - checkpoints[index]) < radius
    completed = collected & (index == last)
    new_index = jnp.where(collected, jnp.minimum(index + 1, last), index)
    return collected, completed, new_index

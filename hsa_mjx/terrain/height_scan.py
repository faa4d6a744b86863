"""The height scan: terrain heights at a grid of points around the robot, turned with its heading.

The grid lies in the robot's heading frame (x along block A -> block B, y to its left), centred on
the robot's position; each point reads the ground under it through the env's own terrain lookup
(``TerrainWorld.ground``: an O(1) interpolation of the tile's height samples, the same function on
the JAX, Warp and C-physics paths; 0 everywhere on the plane scene). A value is the ground height
relative to the robot: ``ground(p) - (z_robot - rest_height)``, with ``z_robot`` the mean height of
the two block origins and ``rest_height`` their height above level ground when the robot rests on
it, so level ground under a resting robot reads about 0 and a wall ahead reads its height. Values
are clipped to +-``clip`` metres, then multiplied by ``scale``. The policy's copy can carry uniform
noise of +-``noise`` metres (drawn per point and step); a privileged critic sees the noise-free copy.

Default grid, 1.6 x 1.2 m at 0.2 m (9 x 7 = 63 points): the robot's footprint is 0.46 x 0.28 m, so
the scan reaches about 0.57 m beyond either end and 0.46 m beside it (several seconds of travel at
its 0.1 m/s), and 0.2 m is the terrain's own sample spacing (10 m / 49): a finer grid only
interpolates between the same samples, a coarser one can miss a 0.4 m pole.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

MAX_POINTS = 4096  # a guard against a spacing typo building a huge observation


@dataclasses.dataclass(frozen=True)
class HeightScanConfig:
    """``observation.height_scan``: the grid of terrain heights around the robot (off by default)."""

    enabled: bool = False
    length: float = 1.6  # m along the heading, centred on the robot
    width: float = 1.2  # m across the heading
    spacing: float = 0.2  # m between points (the terrain's sample spacing)
    noise: float = 0.0  # m, uniform +-noise on the policy's copy (0: exact)
    clip: float = 1.0  # m, heights clipped to +-clip
    scale: float = 1.0  # multiplies the clipped heights


def validate(config: HeightScanConfig) -> HeightScanConfig:
    """Raise ValueError naming the key and its valid range; return the config."""
    for name in ("length", "width"):
        if not getattr(config, name) >= 0:
            raise ValueError(
                f"config key 'observation.height_scan.{name}' must be >= 0 (metres), got {getattr(config, name)!r}"
            )
    for name in ("spacing", "clip", "scale"):
        if not getattr(config, name) > 0:
            raise ValueError(f"config key 'observation.height_scan.{name}' must be > 0, got {getattr(config, name)!r}")
    if not config.noise >= 0:
        raise ValueError(f"config key 'observation.height_scan.noise' must be >= 0 (metres), got {config.noise!r}")
    if config.enabled and num_points(config) > MAX_POINTS:
        raise ValueError(
            f"observation.height_scan: {num_points(config)} points (length {config.length}, width "
            f"{config.width}, spacing {config.spacing}) is over {MAX_POINTS}; widen the spacing"
        )
    return config


def axis(extent: float, spacing: float) -> np.ndarray:
    """Offsets along one axis: every ``spacing`` from -extent / 2 to extent / 2, symmetric about 0."""
    half = int(np.floor(extent / (2.0 * spacing) + 1e-6))
    return (np.arange(-half, half + 1) * spacing).astype(np.float32)


def local_points(config: HeightScanConfig) -> np.ndarray:
    """The scan points in the heading frame, (P, 2): x (ahead) varies fastest, then y (left)."""
    x, y = np.meshgrid(axis(config.length, config.spacing), axis(config.width, config.spacing), indexing="xy")
    return np.stack([x.reshape(-1), y.reshape(-1)], axis=-1)


def num_points(config: HeightScanConfig) -> int:
    """Values the scan adds to an observation (0 when off)."""
    return len(local_points(config)) if config.enabled else 0


def labels(config: HeightScanConfig) -> tuple[str, ...]:
    """A name per scan value: ``height_scan_x<ahead cm>_y<left cm>``."""
    if not config.enabled:
        return ()
    return tuple(f"height_scan_x{round(x * 100):+d}_y{round(y * 100):+d}" for x, y in local_points(config))


def world_points(points: jax.Array, position: jax.Array, unit_heading: jax.Array) -> jax.Array:
    """Heading-frame points (P, 2) in world XY for a robot at ``position`` facing ``unit_heading`` (cos, sin)."""
    cos, sin = unit_heading[0], unit_heading[1]
    x, y = points[:, 0], points[:, 1]
    return position + jnp.stack([cos * x - sin * y, sin * x + cos * y], axis=-1)


def read(
    ground: Callable[[jax.Array], jax.Array],
    points: jax.Array,
    position: jax.Array,
    unit_heading: jax.Array,
    robot_z: jax.Array,
    rest_height: float,
) -> jax.Array:
    """Ground heights (m, unclipped) at the scan points relative to the robot, (P,)."""
    return ground(world_points(points, position, unit_heading)) - (robot_z - rest_height)


def shape(heights: jax.Array, config: HeightScanConfig) -> jax.Array:
    """Clip to +-``clip`` metres, then scale: the values an observation holds."""
    return jnp.clip(heights, -config.clip, config.clip) * config.scale


def add_noise(heights: jax.Array, key: jax.Array, config: HeightScanConfig) -> jax.Array:
    """The policy's copy: uniform +-``noise`` metres per point (unchanged when ``noise`` is 0)."""
    if config.noise <= 0:
        return heights
    return heights + jax.random.uniform(key, heights.shape, jnp.float32, -config.noise, config.noise)

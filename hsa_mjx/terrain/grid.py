"""The heightfield's vertex grid in world coordinates, height lookup and the [0, 1] data mapping.

MuJoCo stores heightfield data row-major with **rows along world y and columns along world x**:
``data[row * ncol + col]`` is the vertex at ``x = -sx + col * 2 sx / (ncol - 1)``,
``y = -sy + row * 2 sy / (nrow - 1)``; the world height is ``data * z_scale`` and each cell is
split into two triangles along the diagonal from (x0, y0) to (x1, y1). Every generator here
returns a (nrow, ncol) array in that layout, so a feature "along x" runs along world x (the
original indexed the first axis as x, which MuJoCo places along world y).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

HFIELD_NAME = "terrain"


@dataclasses.dataclass(frozen=True)
class Grid:
    """Static geometry of one heightfield: vertex counts and MuJoCo's ``size`` (sx, sy, z, base).

    Args:
        nrow: vertices along world y (>= 2).
        ncol: vertices along world x (>= 2).
        half_x, half_y: half extents of the field in metres (> 0).
        z_scale: world height of a data value of 1 (> 0).
        base: thickness of the slab below z = 0 (rendering and collision only).

    Raises:
        ValueError: a count below 2 or a non-positive size.
    """

    nrow: int = 50
    ncol: int = 50
    half_x: float = 5.0
    half_y: float = 5.0
    z_scale: float = 1.5
    base: float = 0.01

    def __post_init__(self) -> None:
        for name in ("nrow", "ncol"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 2:
                raise ValueError(f"terrain grid '{name}' must be an integer >= 2, got {value!r}")
        for name in ("half_x", "half_y", "z_scale"):
            if not getattr(self, name) > 0:
                raise ValueError(f"terrain grid '{name}' must be > 0, got {getattr(self, name)!r}")

    @classmethod
    def from_model(cls, model: mujoco.MjModel, name: str = HFIELD_NAME) -> Grid:
        """The grid of the heightfield asset ``name`` in a compiled MuJoCo model."""
        hid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_HFIELD, name)
        if hid < 0:
            raise ValueError(f"the scene has no heightfield named {name!r}")
        sx, sy, sz, base = (float(v) for v in model.hfield_size[hid])
        return cls(int(model.hfield_nrow[hid]), int(model.hfield_ncol[hid]), sx, sy, sz, base)

    @property
    def spacing_x(self) -> float:
        """Distance between neighbouring vertices along x (m)."""
        return 2.0 * self.half_x / (self.ncol - 1)

    @property
    def spacing_y(self) -> float:
        """Distance between neighbouring vertices along y (m)."""
        return 2.0 * self.half_y / (self.nrow - 1)

    @property
    def size(self) -> int:
        """Number of vertices (length of the flattened data)."""
        return self.nrow * self.ncol

    def xs(self) -> np.ndarray:
        """World x of each column, shape (ncol,)."""
        return np.linspace(-self.half_x, self.half_x, self.ncol, dtype=np.float32)

    def ys(self) -> np.ndarray:
        """World y of each row, shape (nrow,)."""
        return np.linspace(-self.half_y, self.half_y, self.nrow, dtype=np.float32)

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """World (x, y) of every vertex, two arrays of shape (nrow, ncol)."""
        x, y = np.meshgrid(self.xs(), self.ys(), indexing="xy")
        return x, y

    def fraction_to_x(self, fraction: float) -> float:
        """World x of a fraction of the field's width (0 = -x edge, 1 = +x edge)."""
        return -self.half_x + 2.0 * self.half_x * fraction

    def fraction_to_y(self, fraction: float) -> float:
        """World y of a fraction of the field's depth (0 = -y edge, 1 = +y edge)."""
        return -self.half_y + 2.0 * self.half_y * fraction


def to_hfield_data(heights: jax.Array, grid: Grid) -> jax.Array:
    """Map world heights (nrow, ncol) to MuJoCo data in [0, 1], flattened row-major.

    The whole terrain is lifted so that its lowest vertex lies on the heightfield's zero level
    (generators may return negative heights, e.g. craters), then divided by the z scale; anything
    higher than the z scale above that lowest vertex is clipped to 1.
    """
    lifted = heights - jnp.min(heights)
    return jnp.clip(lifted / grid.z_scale, 0.0, 1.0).reshape(-1).astype(jnp.float32)


def surface_height(data: jax.Array, grid: Grid, xy: jax.Array) -> jax.Array:
    """World z of the heightfield surface at points ``xy`` (..., 2), exactly as MuJoCo triangulates it.

    ``data`` is the flattened (nrow * ncol,) heightfield data. Points outside the field take the
    height of the nearest edge. Piecewise linear over the two triangles of each cell (the diagonal
    runs from the cell's (x0, y0) corner to its (x1, y1) corner), so it equals MuJoCo's surface,
    not a bilinear approximation of it.
    """
    heights = data.reshape(grid.nrow, grid.ncol) * grid.z_scale
    u = jnp.clip((xy[..., 0] + grid.half_x) / grid.spacing_x, 0.0, grid.ncol - 1)
    v = jnp.clip((xy[..., 1] + grid.half_y) / grid.spacing_y, 0.0, grid.nrow - 1)
    col = jnp.clip(jnp.floor(u), 0, grid.ncol - 2).astype(jnp.int32)
    row = jnp.clip(jnp.floor(v), 0, grid.nrow - 2).astype(jnp.int32)
    fu, fv = u - col, v - row
    h00, h01 = heights[row, col], heights[row, col + 1]
    h10, h11 = heights[row + 1, col], heights[row + 1, col + 1]
    upper = h00 + fu * (h11 - h10) + fv * (h10 - h00)  # triangle (x0,y0) (x1,y1) (x0,y1)
    lower = h00 + fu * (h01 - h00) + fv * (h11 - h01)  # triangle (x0,y0) (x1,y0) (x1,y1)
    return jnp.where(fv > fu, upper, lower)


def inside(grid: Grid, xy: jax.Array, margin: float) -> jax.Array:
    """True where ``xy`` lies at least ``margin`` inside the field's edges."""
    return (jnp.abs(xy[..., 0]) <= grid.half_x - margin) & (jnp.abs(xy[..., 1]) <= grid.half_y - margin)

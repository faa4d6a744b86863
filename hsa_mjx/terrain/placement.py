"""Where the robot meets the terrain: its footprint, the spawn height that rests it on the surface,
and goals kept on a corridor's centre line."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.pose import move_points
from hsa_mjx.terrain.grid import Grid
from hsa_mjx.terrain.params import CorridorParams

SAMPLES_PER_AXIS = 4  # footprint points per geom along x and y


def _touching_geoms(model: mujoco.MjModel, floor: int) -> list[int]:
    """Robot geoms that can touch the floor: by contype/conaffinity or through an explicit pair."""
    paired = set(model.pair_geom1.tolist()) | set(model.pair_geom2.tolist())
    touching = []
    for g in range(model.ngeom):
        if g == floor or model.geom_bodyid[g] == 0:
            continue
        dynamic = (model.geom_contype[g] & model.geom_conaffinity[floor]) or (
            model.geom_contype[floor] & model.geom_conaffinity[g]
        )
        if dynamic or g in paired:
            touching.append(g)
    return touching


@dataclasses.dataclass(frozen=True)
class Footprint:
    """Static sample points under the robot's floor-touching geoms at the spawn pose.

    ``points`` (P, 2) are world xy; ``drop`` (P,) how far below the block origins the lowest
    surface of the geom above each point lies (0.14 m for the feet, 0.12 m for the block boxes).
    """

    points: np.ndarray
    drop: np.ndarray

    @classmethod
    def from_model(cls, model: mujoco.MjModel, block_body: np.ndarray, floor: str = "floor") -> Footprint:
        """Sample each touching geom's world bounding box at qpos0 (blocks level, robot along x)."""
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        block_z = data.xpos[block_body, 2]
        if not np.allclose(block_z, block_z[0]):
            raise ValueError(f"the blocks of the spawn pose are not level: z = {block_z}")
        points, drops = [], []
        grid = np.linspace(0.0, 1.0, SAMPLES_PER_AXIS)
        for g in _touching_geoms(model, model.geom(floor).id):
            centre = data.geom_xpos[g] + data.geom_xmat[g].reshape(3, 3) @ model.geom_aabb[g, :3]
            half = np.abs(data.geom_xmat[g].reshape(3, 3)) @ model.geom_aabb[g, 3:]
            lo, hi = centre - half, centre + half
            xs, ys = lo[0] + grid * (hi[0] - lo[0]), lo[1] + grid * (hi[1] - lo[1])
            for x in xs:
                for y in ys:
                    points.append((x, y))
                    drops.append(block_z[0] - lo[2])
        return cls(np.asarray(points, np.float32), np.asarray(drops, np.float32))

    def spawn_height(
        self,
        ground: Callable[[jax.Array], jax.Array],
        clearance: float,
        move: tuple[jax.Array, jax.Array, jax.Array] | None = None,
    ) -> jax.Array:
        """Block-origin z that leaves ``clearance`` under the robot's lowest point, robot level, on the
        surface ``ground(xy) -> z``; ``move`` = (centre, target, yaw) for a robot moved as by
        ``pose.move_points``."""
        points = jnp.asarray(self.points)
        if move is not None:
            points = move_points(points, *move)
        return jnp.max(ground(points) + self.drop) + clearance


def onto_line(goal_xy: jax.Array, point: jax.Array, direction: jax.Array, limit: float) -> jax.Array:
    """Move a goal onto the line ``point + t * direction``: same distance from the origin (at most
    ``limit``), on the side the goal was on (a corridor's goals stay on its floor)."""
    side = jnp.where(jnp.dot(goal_xy, direction) < 0.0, -1.0, 1.0)
    return point + side * jnp.minimum(jnp.linalg.norm(goal_xy), limit) * direction


def corridor_line(params: CorridorParams, grid: Grid, edge_margin: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The corridor's centre line: a point on it nearest the origin, its unit direction, and the
    largest distance from the origin a goal may have along it (inside the field's edge margin)."""
    if params.axis == "x":
        return (
            np.array([0.0, grid.fraction_to_y(params.center)], np.float32),
            np.array([1.0, 0.0], np.float32),
            grid.half_x - edge_margin,
        )
    return (
        np.array([grid.fraction_to_x(params.center), 0.0], np.float32),
        np.array([0.0, 1.0], np.float32),
        grid.half_y - edge_margin,
    )

"""How far the robot is from its goal, how it advances along a checkpoint track, and whether it stalls.

``reward.progress`` chooses the measure of the distance and forward terms and of the logged
``distance_to_goal``: ``euclidean`` (the original's straight line) or ``geodesic`` (the path along the
ground the robot can cross, read from the distance field of the goal's site on the env's tile:
``hsa_mjx.terrain.geodesic``). An episode whose goal is no site (``set_goal``, a radial draw with no site in
range) falls back to the straight line. Success is always the straight-line distance to the goal.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hsa_mjx.config import EnvConfig
from hsa_mjx.task import goals, observation
from hsa_mjx.task.types import TaskState
from hsa_mjx.terrain.world import TerrainWorld

NO_SITE = -1  # TaskState.site of a goal without a distance field


class GoalProgress:
    """The goal measures of one env config on its terrain (static); pure functions of the task state."""

    def __init__(self, config: EnvConfig, world: TerrainWorld):
        self.config, self.world = config, world
        self.geodesic = config.reward.progress == "geodesic"
        if self.geodesic and not world.has_sites:
            raise ValueError("reward.progress 'geodesic' needs the terrain's goal sites (terrain.reachability)")

    def measure(self, task: TaskState, xy: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(distance, unit direction) from ``xy`` to the current goal, as ``reward.progress`` measures it."""
        straight, towards = observation.goal_vector(xy, task.goal_xy)
        if not self.geodesic:
            return straight, towards
        path, along = self.world.path_to_goal(task.tile, jnp.maximum(task.site, 0), xy)
        has_site = task.site >= 0
        along = jnp.where(jnp.any(along != 0.0), along, towards)  # on the site itself: the straight way
        return jnp.where(has_site, path, straight), jnp.where(has_site, along, towards)

    def place_goal(
        self,
        key: jax.Array,
        tile: jax.Array,
        terrain_id: jax.Array,
        goal_range: jax.Array,
        checkpoint: jax.Array,
        goal_xy: jax.Array,
    ) -> tuple[jax.Array, jax.Array]:
        """(site, goal): a radial goal moved to a goal site of the tile (with sites) or to reachable ground
        (with reachability), a corridor goal onto the corridor's floor; a spiral goal's site is its
        checkpoint (with geodesic progress); other goals have none (-1)."""
        site = jnp.asarray(NO_SITE, jnp.int32)
        radial, bearing = self.config.goal.mode == "radial", tuple(self.config.goal.radial_bearing_deg)
        if radial and self.world.has_sites:  # static
            return self.world.site_goal(jax.random.fold_in(key, 1), tile, goal_range, bearing)
        if radial and self.world.reachable_goals:
            return site, self.world.reachable_goal(jax.random.fold_in(key, 1), tile, goal_range, bearing, goal_xy)
        if self.config.goal.mode == "spiral" and self.geodesic:
            site = checkpoint
        return site, self.world.place_goal(goal_xy, terrain_id)

    def advance_checkpoint(self, task: TaskState, xy: jax.Array) -> tuple[TaskState, jax.Array, jax.Array]:
        """Spiral: collect the current checkpoint when within ``checkpoint_radius`` and aim at the next one
        (its site: the checkpoint's own field); returns (task, collected, completed)."""
        if self.config.goal.mode != "spiral":
            return task, jnp.zeros((), bool), jnp.zeros((), bool)
        collected, completed, index = goals.advance_checkpoint(
            xy, task.checkpoints, task.checkpoint_index, self.config.goal.checkpoint_radius
        )
        site = index if self.geodesic else task.site
        task = task.replace(goal_xy=task.checkpoints[index], checkpoint_index=index, site=site)
        # Measure progress towards the new checkpoint from here: no distance reward on a switch.
        new_prev = jnp.where(collected, self.measure(task, xy)[0], task.prev_distance)
        return task.replace(prev_distance=new_prev), collected, completed


def record_position(task: TaskState, position: jax.Array) -> tuple[TaskState, jax.Array, jax.Array]:
    """Append to the stagnation window; return the task, the displacement over the window and whether the
    window is full."""
    window = task.com_history.shape[0]
    history = task.com_history.at[task.history_count % window].set(position)
    count = task.history_count + 1
    oldest = history[count % window]
    return (
        task.replace(com_history=history, history_count=count),
        jnp.linalg.norm(position - oldest),
        count >= window,
    )

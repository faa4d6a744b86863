"""The curricula as one state the training loop owns, and the episode parameters they choose.

The batch env reports episode ends (:class:`EpisodeEnds`); :class:`CurriculumRules` turns them into
the next :class:`~hsa_mjx.task.params.EnvParams` of every env: the goal curriculum's radial range
(one range for all envs, moved per collection from every device's outcomes), the terrain
curriculum's cell of each env and the randomisation curriculum's level of each env (both moved where
its episode ends, before the env resets). The rules read
nothing but their configs and the arrays they are given: no env state, no key of their own. Nothing
else holds curriculum state: the batch env and the Gymnasium vector env reset from the parameters
they are given.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hsa_mjx.config import EnvConfig
from hsa_mjx.curricula import goal_curriculum, randomization_curriculum, terrain_curriculum
from hsa_mjx.task.params import FREE_CELL, EnvParams


@struct.dataclass
class Curricula:
    """The goal curriculum (shared by all envs), each env's terrain cell with per-cell episode sums, and
    each env's randomisation level."""

    goal: goal_curriculum.GoalCurriculumState
    terrain: terrain_curriculum.TerrainLevels  # (B,) each; zeros without the terrain curriculum
    cell_totals: dict[str, jax.Array]  # per-cell episodes and successes since the last drain; empty without
    randomization: jax.Array  # (B,) float32 share of the randomisation ranges; ones without its curriculum


@struct.dataclass
class EnvLevels:
    """Every env's levels as a resumed run restores them, (B,) arrays; a None part starts afresh."""

    terrain: terrain_curriculum.TerrainLevels | None = None
    randomization: jax.Array | None = None  # float32 shares of the randomisation ranges


def host_levels(states: list[Curricula]) -> dict[str, np.ndarray]:
    """Every env's levels as flat host arrays from per-device curricula (device order), for a checkpoint:
    the terrain curriculum's fields and ``randomization``."""
    levels = terrain_curriculum.to_host([jax.device_get(s.terrain) for s in states])
    levels["randomization"] = np.concatenate([np.asarray(s.randomization).reshape(-1) for s in states])
    return levels


@struct.dataclass
class EpisodeEnds:
    """What one batch step tells the terrain curriculum, (B,) each: which episodes ended, which reached
    their goal, and the share of their start distance to the goal they covered."""

    done: jax.Array
    success: jax.Array
    progress: jax.Array


class CurriculumRules:
    """The static side: which curricula run and how they map to episode parameters.

    The configs are taken as built (a training config checks that they fit the env when it is built:
    the goal curriculum needs radial goals, the terrain curriculum per-env terrain).

    Args:
        env: the env's config (its goal range and terrain).
        goal: goal curriculum settings (off when None).
        terrain: terrain curriculum settings (off when None).
        randomization: randomisation curriculum settings (off when None).
    """

    def __init__(
        self,
        env: EnvConfig,
        goal: goal_curriculum.GoalCurriculumConfig | None = None,
        terrain: terrain_curriculum.TerrainCurriculumConfig | None = None,
        randomization: randomization_curriculum.RandomizationCurriculumConfig | None = None,
    ):
        self.env = env
        self.goal = goal or goal_curriculum.GoalCurriculumConfig(enabled=False)
        self.terrain = terrain or terrain_curriculum.TerrainCurriculumConfig()
        self.randomization = randomization or randomization_curriculum.RandomizationCurriculumConfig()
        self.start = tuple(env.goal.radial_range)  # where the goal curriculum's range starts
        self.cells = len(env.terrain.types) * env.terrain.levels

    def init(
        self,
        keys: jax.Array,
        goal: goal_curriculum.GoalCurriculumState | None = None,
        restored: EnvLevels | None = None,
    ) -> Curricula:
        """Start states for a batch (one key per env); a given goal state or levels are kept (resume)."""
        goal = goal if goal is not None else goal_curriculum.init(self.goal, self.start)
        restored = restored or EnvLevels()
        levels = restored.terrain
        if levels is None:
            levels = (
                terrain_curriculum.init(keys, self.terrain, self.env.terrain)
                if self.terrain.enabled
                else terrain_curriculum.placeholder(keys.shape[0])
            )
        sums = {}
        if self.terrain.enabled:
            sums = {k: jnp.zeros((self.cells,), jnp.float32) for k in terrain_curriculum.OUTCOME_KEYS}
        scale = restored.randomization
        if scale is None or not self.randomization.enabled:
            scale = randomization_curriculum.init(keys.shape[0], self.randomization)
        return Curricula(goal=goal, terrain=levels, cell_totals=sums, randomization=scale)

    def params(self, state: Curricula) -> EnvParams:
        """Every env's parameters for its next episode, (B,) leading axis."""
        batch = state.terrain.level.shape[0]
        goal_range = (
            goal_curriculum.goal_range(state.goal, self.goal, self.start)
            if self.goal.enabled
            else jnp.asarray(self.start, jnp.float32)
        )
        cells = (
            state.terrain.cells()
            if self.terrain.enabled
            else jnp.broadcast_to(jnp.asarray(FREE_CELL, jnp.int32), (batch, 2))
        )
        return EnvParams(
            goal_range=jnp.broadcast_to(goal_range, (batch, 2)),
            terrain_cell=cells,
            randomization_scale=state.randomization,
        )

    def after_step(self, state: Curricula, ends: EpisodeEnds, keys: jax.Array) -> Curricula:
        """Move the envs whose episode ended: their randomisation level, and their terrain level after
        counting the episode in the cell it ran on.

        ``keys``: one PRNG key per env, for the level of an env promoted from the top (``top_redraw``).
        """
        done, success = ends.done > 0, ends.success > 0
        if self.randomization.enabled:
            scale = randomization_curriculum.update(state.randomization, done, success, self.randomization)
            state = state.replace(randomization=scale)
        if not self.terrain.enabled:
            return state
        levels = self.env.terrain.levels
        outcomes = terrain_curriculum.cell_outcomes(state.terrain, done, success, self.cells, levels)
        terrain = terrain_curriculum.update(state.terrain, done, success, ends.progress, self.terrain, levels, keys)
        totals = {k: v + outcomes[k] for k, v in state.cell_totals.items()}
        return state.replace(terrain=terrain, cell_totals=totals)

    def after_collection(
        self, goal: goal_curriculum.GoalCurriculumState, success: jax.Array, done: jax.Array
    ) -> goal_curriculum.GoalCurriculumState:
        """The goal curriculum fed with episode ends, (steps, all envs) in step order."""
        if not self.goal.enabled:
            return goal

        def update(state, outcome):
            return goal_curriculum.update(state, outcome[0], outcome[1], self.goal, self.start), None

        return jax.lax.scan(update, goal, (success, done))[0]

    def goal_metrics(self, goal: goal_curriculum.GoalCurriculumState) -> dict[str, jax.Array]:
        """The goal curriculum's ``curriculum/*`` log keys."""
        return goal_curriculum.metrics(goal, self.goal, self.start)

    def drain(self, state: Curricula) -> tuple[Curricula, dict[str, jax.Array]]:
        """The per-cell sums by name and the levels' snapshots (logs), and the state with the sums zeroed."""
        totals = randomization_curriculum.totals(state.randomization) if self.randomization.enabled else {}
        if not self.terrain.enabled:
            return state, totals
        types, levels = tuple(self.env.terrain.types), self.env.terrain.levels
        totals.update(terrain_curriculum.totals(state.terrain, types, levels))
        totals.update(terrain_curriculum.name_outcomes(state.cell_totals, types, levels))
        return state.replace(cell_totals=jax.tree.map(jnp.zeros_like, state.cell_totals)), totals

"""Both curricula as one state the training loop owns, and the episode parameters they choose.

The batch env reports episode ends; :class:`CurriculumRules` turns them into the next
:class:`~hsa_mjx.task.params.EnvParams` of every env: the goal curriculum's radial range (one range
for all envs, moved per collection from every device's outcomes) and the terrain curriculum's cell
of each env (moved where its episode ends, before the env resets). Nothing else holds curriculum
state: the batch env and the Gymnasium vector env reset from the parameters they are given.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from hsa_mjx.curricula import goal as cur
from hsa_mjx.curricula import terrain as tcur
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.task.params import FREE_CELL, EnvParams
from hsa_mjx.task.types import EnvState


@struct.dataclass
class Curricula:
    """The goal curriculum (shared by all envs) and each env's terrain cell, with per-cell episode sums."""

    goal: cur.CurriculumState
    terrain: tcur.TerrainLevels  # (B,) each; zeros without the terrain curriculum
    cell_totals: dict[str, jax.Array]  # per-cell episodes and successes since the last drain; empty without


class CurriculumRules:
    """The static side: which curricula run and how they map to episode parameters.

    Args:
        env: the single env (its goal mode, terrain and spawn point).
        goal: goal curriculum settings (needs ``goal.mode: radial`` when enabled).
        terrain: terrain curriculum settings (needs per-env terrain when enabled).
    """

    def __init__(
        self, env: HSAEnv, goal: cur.CurriculumConfig | None = None, terrain: tcur.TerrainCurriculumConfig | None = None
    ):
        self.env = env
        self.goal = goal or cur.CurriculumConfig(enabled=False)
        if self.goal.enabled and env.config.goal.mode != "radial":
            raise ValueError(f"the goal curriculum needs env goal.mode 'radial', got {env.config.goal.mode!r}")
        self.terrain = tcur.validate(
            terrain or tcur.TerrainCurriculumConfig(), env.config.terrain, env.world.per_env, env.config.goal.mode
        )
        self.cells = len(env.config.terrain.types) * env.config.terrain.levels

    def init(
        self, keys: jax.Array, goal: cur.CurriculumState | None = None, levels: tcur.TerrainLevels | None = None
    ) -> Curricula:
        """Start states for a batch (one key per env); a given goal state or levels are kept (resume)."""
        goal = goal if goal is not None else cur.init(self.goal)
        if levels is None:
            levels = (
                tcur.init(keys, self.terrain, self.env.config.terrain)
                if self.terrain.enabled
                else tcur.placeholder(keys.shape[0])
            )
        sums = {k: jnp.zeros((self.cells,), jnp.float32) for k in tcur.OUTCOME_KEYS} if self.terrain.enabled else {}
        return Curricula(goal=goal, terrain=levels, cell_totals=sums)

    def params(self, state: Curricula) -> EnvParams:
        """Every env's parameters for its next episode, (B,) leading axis."""
        batch = state.terrain.level.shape[0]
        goal_range = (
            cur.goal_range(state.goal, self.goal)
            if self.goal.enabled
            else jnp.asarray(self.env.config.goal.radial_range, jnp.float32)
        )
        cells = (
            state.terrain.cells()
            if self.terrain.enabled
            else jnp.broadcast_to(jnp.asarray(FREE_CELL, jnp.int32), (batch, 2))
        )
        return EnvParams(goal_range=jnp.broadcast_to(goal_range, (batch, 2)), terrain_cell=cells)

    def after_step(self, state: Curricula, stepped: EnvState) -> Curricula:
        """Count the episodes that ended in the cell they ran on, then move those envs up or down a level."""
        if not self.terrain.enabled:
            return state
        done, success = stepped.done > 0, stepped.metrics["termination/goal_reached"] > 0
        levels = self.env.config.terrain.levels
        outcomes = tcur.cell_outcomes(state.terrain, done, success, self.cells, levels)
        start = jnp.linalg.norm(stepped.pipeline_state.task.goal_xy - self.env.spawn_xy, axis=-1)
        progress = 1.0 - stepped.metrics["distance_to_goal"] / jnp.maximum(start, 1e-6)
        terrain = tcur.update(
            state.terrain, done, success, progress, self.terrain, levels, stepped.pipeline_state.task.rng
        )
        return state.replace(terrain=terrain, cell_totals={k: v + outcomes[k] for k, v in state.cell_totals.items()})

    def after_collection(self, goal: cur.CurriculumState, success: jax.Array, done: jax.Array) -> cur.CurriculumState:
        """The goal curriculum fed with episode ends, (steps, all envs) in step order."""
        if not self.goal.enabled:
            return goal
        update = lambda c, sd: (cur.update(c, sd[0], sd[1], self.goal), None)  # noqa: E731
        return jax.lax.scan(update, goal, (success, done))[0]

    def drain(self, state: Curricula) -> tuple[Curricula, dict[str, jax.Array]]:
        """The per-cell sums by name and the levels' snapshot (logs), and the state with the sums zeroed."""
        if not self.terrain.enabled:
            return state, {}
        terrain = self.env.config.terrain
        totals = tcur.totals(state.terrain, tuple(terrain.types), terrain.levels)
        totals.update(tcur.name_outcomes(state.cell_totals, tuple(terrain.types), terrain.levels))
        return state.replace(cell_totals=jax.tree.map(jnp.zeros_like, state.cell_totals)), totals

"""A batch of envs for training: per-env auto-reset with fresh goals, the curriculum, episode statistics.

Brax's ``AutoResetWrapper`` restores each env's cached first state, so every episode of an env
would replay the same goal (and terrain). Here a finished env is reset from its own PRNG key with a
goal drawn from the curriculum's current range: every episode differs. The batch-level wrapper
also owns the curriculum state (one copy, updated from all envs, gathered across devices under
``pmap``) and sums episode statistics on the device until the host drains them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from hsa_mjx.sim import backend

from hsa_mjx.task import reward, termination
from hsa_mjx.curricula import goal as cur
from hsa_mjx.curricula import terrain as tcur
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.task.types import EnvState, SimState

TOTAL_KEYS = ("episodes", "return", "length", "success", "final_distance", "env_steps",
              "nonfinite_action", "nonfinite_state", "step_reward", "step_distance", "step_checkpoint")


@struct.dataclass
class EpisodeAccumulator:
    """Running sums of the current episode of every env, shape (B,) each."""

    ret: jax.Array
    length: jax.Array
    terms: dict[str, jax.Array]


@struct.dataclass
class BatchState:
    """State of a batch of training envs (``env`` fields have a leading batch axis)."""

    env: EnvState
    curriculum: cur.CurriculumState
    episode: EpisodeAccumulator
    totals: dict[str, jax.Array]  # scalar sums over episodes finished since the last drain
    terrain: tcur.TerrainLevels  # every env's terrain type and level (zeros without the terrain curriculum)

    @property
    def obs(self) -> jax.Array:
        return self.env.obs


def _zero_totals() -> dict[str, jax.Array]:
    names = TOTAL_KEYS + tuple(f"reward/{k}" for k in reward.TERM_NAMES) + tuple(
        f"termination/{k}" for k in termination.REASONS)
    return {name: jnp.zeros((), jnp.float32) for name in names}


class AutoResetEnv:
    """Batched ``reset(keys)`` / ``step(state, actions)`` over an :class:`HSAEnv` with curriculum.

    Args:
        env: the single-env :class:`HSAEnv`.
        curriculum: curriculum settings; when enabled the env must use ``goal.mode: radial``.
        axis_name: the ``pmap`` axis to gather episode outcomes over (None on one device).
        step_curriculum: update the curriculum inside ``step`` (True); False leaves it to the
            caller (the PPO learner feeds it each collection's outcomes, ``train.ppo``).
        terrain_curriculum: the per-env terrain level curriculum (``hsa_mjx.curricula.terrain``);
            it moves each env's level where its episode ends, before the env is reset.
    """

    def __init__(self, env: HSAEnv, curriculum: cur.CurriculumConfig | None = None,
                 axis_name: str | None = None, step_curriculum: bool = True,
                 terrain_curriculum: tcur.TerrainCurriculumConfig | None = None):
        self.env = env
        self.curriculum = curriculum or cur.CurriculumConfig(enabled=False)
        if self.curriculum.enabled and env.config.goal.mode != "radial":
            raise ValueError(f"the goal curriculum needs env goal.mode 'radial', got {env.config.goal.mode!r}")
        self.terrain_curriculum = tcur.validate(terrain_curriculum or tcur.TerrainCurriculumConfig(),
                                                env.config.terrain, env.world.per_env, env.config.goal.mode)
        self.axis_name, self.step_curriculum = axis_name, step_curriculum

    @property
    def observation_size(self) -> int:
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        return self.env.action_size

    def _goal_range(self, state: cur.CurriculumState) -> jax.Array:
        if self.curriculum.enabled:
            return cur.goal_range(state, self.curriculum)
        return jnp.asarray(self.env.config.goal.radial_range, jnp.float32)

    def reset(self, keys: jax.Array, curriculum_state: cur.CurriculumState | None = None,
              terrain_levels: tcur.TerrainLevels | None = None) -> BatchState:
        """Reset a batch (one key per env); given curriculum states are kept (resume)."""
        check_batch(self.env, keys.shape[0])
        batch = keys.shape[0]
        cstate = curriculum_state if curriculum_state is not None else cur.init(self.curriculum)
        levels = terrain_levels if terrain_levels is not None else self._initial_levels(keys)
        env_state = self._reset_all(keys, self._goal_range(cstate), levels)
        zeros = jnp.zeros((batch,), jnp.float32)
        episode = EpisodeAccumulator(ret=zeros, length=zeros, terms={k: zeros for k in reward.TERM_NAMES})
        return BatchState(env=env_state, curriculum=cstate, episode=episode, totals=self._zero_totals(), terrain=levels)

    def _zero_totals(self) -> dict[str, jax.Array]:
        """Zeroed totals; with the terrain curriculum also per-cell episode and success sums, (cells,) each."""
        totals = _zero_totals()
        if self.terrain_curriculum.enabled:
            cells = len(self.env.config.terrain.types) * self.env.config.terrain.levels
            totals.update({k: jnp.zeros((cells,), jnp.float32) for k in tcur.OUTCOME_KEYS})
        return totals

    def _initial_levels(self, keys: jax.Array) -> tcur.TerrainLevels:
        """The terrain curriculum's start levels, or the placeholder without it."""
        if self.terrain_curriculum.enabled:
            return tcur.init(keys, self.terrain_curriculum, self.env.config.terrain)
        return tcur.placeholder(keys.shape[0])

    def _reset_all(self, keys: jax.Array, goal_range: jax.Array, levels: tcur.TerrainLevels) -> EnvState:
        """Fresh episodes for every env: on its curriculum cell, or on a freely drawn tile without it."""
        if self.terrain_curriculum.enabled:
            return jax.vmap(self.env.reset_with_goal_range, in_axes=(0, None, 0))(keys, goal_range, levels.cells())
        return jax.vmap(self.env.reset_with_goal_range, in_axes=(0, None))(keys, goal_range)

    def step(self, state: BatchState, actions: jax.Array) -> BatchState:
        """Step every env; reset the finished ones with fresh goals; update curriculum and totals."""
        return self.step_with_final(state, actions)[0]

    def step_with_final(self, state: BatchState, actions: jax.Array, reset_metrics: bool = False
                        ) -> tuple[BatchState, EnvState, EpisodeAccumulator]:
        """``step``, also returning what the auto-reset replaces.

        Returns (new batch state, every env's state after the step and before the auto-reset:
        the terminal state where it finished, the sums of the episode that step ended or
        continued). ``reset_metrics`` (static) also gives the reset envs their fresh episodes'
        metrics (zero rewards, no reasons, the new goal distance) instead of the terminal ones.
        """
        nxt = jax.vmap(self.env.step)(state.env, actions)
        done = nxt.done > 0
        episode = EpisodeAccumulator(
            ret=state.episode.ret + nxt.reward, length=state.episode.length + 1.0,
            terms={k: v + nxt.metrics[f"reward/{k}"] for k, v in state.episode.terms.items()})
        totals = self._add_totals(state.totals, nxt, episode, done)
        if self.terrain_curriculum.enabled:  # per cell, on the level each ended episode ran on
            terrain = self.env.config.terrain
            outcomes = tcur.cell_outcomes(state.terrain, done, nxt.metrics["termination/goal_reached"] > 0,
                                          len(terrain.types) * terrain.levels, terrain.levels)
            totals = {**totals, **{k: totals[k] + v for k, v in outcomes.items()}}
        cstate = self._update_curriculum(state.curriculum, nxt.metrics["termination/goal_reached"] > 0, done)
        levels = self._update_levels(state.terrain, nxt, done)
        env_state = self._reset_done(nxt, done, cstate, levels, reset_metrics)
        keep = lambda x: jnp.where(done, jnp.zeros_like(x), x)  # noqa: E731
        running = EpisodeAccumulator(ret=keep(episode.ret), length=keep(episode.length),
                                     terms={k: keep(v) for k, v in episode.terms.items()})
        return BatchState(env=env_state, curriculum=cstate, episode=running, totals=totals,
                          terrain=levels), nxt, episode

    def _update_levels(self, levels: tcur.TerrainLevels, nxt: EnvState, done: jax.Array) -> tcur.TerrainLevels:
        """Move the envs whose episode ended up or down a terrain level (their next episode's level)."""
        if not self.terrain_curriculum.enabled:
            return levels
        start = jnp.linalg.norm(nxt.pipeline_state.task.goal_xy - self.env.spawn_xy, axis=-1)
        progress = 1.0 - nxt.metrics["distance_to_goal"] / jnp.maximum(start, 1e-6)
        return tcur.update(levels, done, nxt.metrics["termination/goal_reached"] > 0, progress,
                           self.terrain_curriculum, self.env.config.terrain.levels, nxt.pipeline_state.task.rng)

    def _update_curriculum(self, cstate: cur.CurriculumState, success: jax.Array,
                           done: jax.Array) -> cur.CurriculumState:
        """Feed this step's episode ends (from every device) to the curriculum."""
        if not (self.curriculum.enabled and self.step_curriculum):
            return cstate
        if self.axis_name is not None:
            success = jax.lax.all_gather(success, self.axis_name)
            done = jax.lax.all_gather(done, self.axis_name)
        return cur.update(cstate, success, done, self.curriculum)

    def _reset_done(self, nxt: EnvState, done: jax.Array, cstate: cur.CurriculumState,
                    levels: tcur.TerrainLevels, reset_metrics: bool = False) -> EnvState:
        """Replace finished envs by fresh episodes drawn from their own keys (skipped if none ended)."""
        def fresh(state: EnvState) -> EnvState:
            keys = jax.vmap(lambda k: jax.random.split(k)[1])(state.pipeline_state.task.rng)
            new = self._reset_all(keys, self._goal_range(cstate), levels)
            pick = per_env_picker(done)
            metrics = jax.tree.map(pick, new.metrics, state.metrics) if reset_metrics else state.metrics
            sim = select_sim(done, new.pipeline_state, state.pipeline_state)
            info = dict(state.info)  # truncation stays the step's; privileged inputs follow the observation
            if "privileged_obs" in info:
                info["privileged_obs"] = pick(new.info["privileged_obs"], info["privileged_obs"])
            return state.replace(pipeline_state=sim, obs=pick(new.obs, state.obs), metrics=metrics, info=info)
        return jax.lax.cond(jnp.any(done), fresh, lambda s: s, nxt)

    @staticmethod
    def _add_totals(totals: dict, nxt: EnvState, episode: EpisodeAccumulator, done: jax.Array) -> dict:
        """Add the finished episodes (and per-step counters) to the running totals."""
        d = done.astype(jnp.float32)
        m = nxt.metrics
        add = {
            "episodes": jnp.sum(d), "return": jnp.sum(d * episode.ret), "length": jnp.sum(d * episode.length),
            "success": jnp.sum(d * m["termination/goal_reached"]),
            "final_distance": jnp.sum(d * m["distance_to_goal"]),
            "env_steps": jnp.asarray(done.shape[0], jnp.float32),
            "nonfinite_action": jnp.sum(m["nonfinite_action"]),
            "nonfinite_state": jnp.sum(m["termination/non_finite"]),
            # per env step, finished or not: what long episodes (corridor, spiral) show before they end
            "step_reward": jnp.sum(nxt.reward), "step_distance": jnp.sum(m["distance_to_goal"]),
            "step_checkpoint": jnp.sum(m["checkpoint_index"]),
        }
        add.update({f"reward/{k}": jnp.sum(d * v) for k, v in episode.terms.items()})
        add.update({f"termination/{k}": jnp.sum(d * m[f"termination/{k}"]) for k in termination.REASONS})
        return {**totals, **{k: totals[k] + add[k] for k in add}}

    def drain(self, state: BatchState) -> tuple[BatchState, dict[str, jax.Array]]:
        """Return the totals (with the terrain levels' snapshot) and the state with them zeroed (between jitted chunks)."""
        totals = dict(state.totals)
        if self.terrain_curriculum.enabled:
            terrain = self.env.config.terrain
            totals.update(tcur.totals(state.terrain, tuple(terrain.types), terrain.levels))
            outcomes = {k: totals.pop(k) for k in tcur.OUTCOME_KEYS}
            totals.update(tcur.name_outcomes(outcomes, tuple(terrain.types), terrain.levels))
        return state.replace(totals=jax.tree.map(jnp.zeros_like, state.totals)), totals


def per_env_picker(mask: jax.Array):
    """``pick(a, b)``: ``a`` where ``mask`` (one bool per env, the leading axis), else ``b``."""
    return lambda a, b: jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)


def select_sim(mask: jax.Array, a: SimState, b: SimState) -> SimState:
    """Per env, the simulator state of ``a`` where ``mask``, else of ``b`` (Warp's shared buffers kept)."""
    return SimState(physics=backend.select(mask, a.physics, b.physics),
                    task=jax.tree.map(per_env_picker(mask), a.task, b.task))


def check_batch(env: HSAEnv, batch: int) -> None:
    """Refuse a batch larger than a Warp env's shared contact buffer was sized for (``HSAEnv(num_envs=...)``)."""
    if env.physics_backend == "warp" and batch > env.num_envs:
        raise ValueError(f"a batch of {batch} envs on the Warp backend needs an env built for at least that many: "
                         f"HSAEnv(config, num_envs={batch}) (this one shares its contact buffer among {env.num_envs})")


def summarize(totals: dict[str, float], levels: int = 1) -> dict[str, float]:
    """Turn drained totals (host floats, summed over devices) into per-episode means and rates
    (and the terrain curriculum's levels, of ``levels``).

    Per-episode keys are left out when no episode ended in the period (rather than logged as 0).
    """
    out = {"episodes": totals["episodes"], "env_steps": totals["env_steps"],
           "nonfinite/actions": totals["nonfinite_action"], "nonfinite/states": totals["nonfinite_state"]}
    steps = max(totals["env_steps"], 1.0)
    out.update({"step/reward": totals["step_reward"] / steps, "step/distance_to_goal": totals["step_distance"] / steps,
                "step/checkpoint_index": totals["step_checkpoint"] / steps})
    out.update(tcur.summarize(totals, levels))
    episodes = totals["episodes"]
    if episodes <= 0:
        return out
    out.update({"episode/return": totals["return"] / episodes, "episode/length": totals["length"] / episodes,
                "episode/success_rate": totals["success"] / episodes,
                "episode/final_distance": totals["final_distance"] / episodes})
    for key, value in totals.items():
        if key.startswith("reward/"):
            out[f"episode/{key}"] = value / episodes
        elif key.startswith("termination/"):
            out[key] = value / episodes
    return out

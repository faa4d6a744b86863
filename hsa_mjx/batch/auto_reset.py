"""A batch of envs: per-env auto-reset with fresh episodes, and episode statistics on the device.

Brax's ``AutoResetWrapper`` restores each env's cached first state, so every episode of an env
would replay the same goal (and terrain). Here a finished env is reset from its own PRNG key with
the episode parameters it is given (``EnvParams``, one per env: the training loop's curricula choose
them, ``HSAEnv.default_params`` otherwise): every episode differs. Episode statistics are summed on
the device until the host drains them. The batch holds no curriculum state.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from hsa_mjx.curricula import randomization_curriculum, terrain_curriculum
from hsa_mjx.curricula.state import EpisodeEnds
from hsa_mjx.sim import backend
from hsa_mjx.task import reward, termination
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.task.params import EnvParams
from hsa_mjx.task.types import EnvState, SimState
from hsa_mjx.terrain.regeneration import Regenerator, TerrainTiles

TOTAL_KEYS = (
    "episodes",
    "return",
    "length",
    "success",
    "final_distance",
    "env_steps",
    "nonfinite_action",
    "nonfinite_state",
    "step_reward",
    "step_distance",
    "step_checkpoint",
    "redraw_truncations",  # episodes cut short because the terrain tile under them was re-drawn
)


@struct.dataclass
class EpisodeAccumulator:
    """Running sums of the current episode of every env, shape (B,) each."""

    ret: jax.Array
    length: jax.Array
    terms: dict[str, jax.Array]


@struct.dataclass
class BatchState:
    """State of a batch of envs (``env`` fields have a leading batch axis)."""

    env: EnvState
    episode: EpisodeAccumulator
    totals: dict[str, jax.Array]  # scalar sums over episodes finished since the last drain
    terrain: TerrainTiles | None = None  # the pool's arrays, with terrain regeneration (no batch axis)

    @property
    def obs(self) -> jax.Array:
        return self.env.obs


def _zero_totals() -> dict[str, jax.Array]:
    names = (
        TOTAL_KEYS
        + tuple(f"reward/{k}" for k in reward.TERM_NAMES)
        + tuple(f"termination/{k}" for k in (*termination.REASONS, *termination.GROUPS))
    )
    return {name: jnp.zeros((), jnp.float32) for name in names}


class AutoResetEnv:
    """Batched ``reset(keys, params)`` / ``step(state, actions, params)`` over an :class:`HSAEnv`.

    ``params`` (``EnvParams`` with a leading batch axis) are the parameters of the episodes that
    start: at ``reset`` for every env, at ``step`` for the envs whose episode ended.
    ``advance`` and ``reset_done`` are the two halves of ``step``, for a caller that updates its
    curricula from the episodes that ended before the envs reset (the trainer's learner).
    """

    def __init__(self, env: HSAEnv, regenerate_every: int = 0):
        """``regenerate_every`` > 0: the batch carries the terrain tiles and :meth:`tick` re-draws the random
        ones every that many calls (``hsa_mjx.terrain.regeneration``)."""
        self.env, self.regenerate_every = env, int(regenerate_every)
        if self.regenerate_every > 0 and env.physics_backend == "c":
            raise ValueError(
                "terrain regeneration needs MJX physics (physics.backend jax or warp): C MuJoCo substeps read the "
                "heightfield of the host model, which the re-drawn tiles do not reach"
            )
        self.regenerator = Regenerator(env.world) if self.regenerate_every > 0 else None

    def bound(self, state: BatchState) -> HSAEnv:
        """The env on the batch's terrain tiles (the env itself without regeneration)."""
        return self.env if state.terrain is None else self.env.with_terrain(state.terrain)

    def tick(self, state: BatchState, key: jax.Array, params: EnvParams | None = None) -> BatchState:
        """One training iteration passed: re-draw the random tiles from ``key`` when ``regenerate_every``
        iterations have passed since the last time (no-op without regeneration). Episodes on a re-written
        tile are truncated (``hsa_mjx.terrain.regeneration``): they restart with ``params`` (default: the
        env's), their partial episode counted in ``totals["redraw_truncations"]`` alone."""
        if self.regenerator is None:
            return state
        terrain = state.terrain.replace(age=state.terrain.age + 1)
        due = terrain.age >= self.regenerate_every
        terrain = jax.lax.cond(due, lambda t: self.regenerator.regenerate(key, t).replace(age=0), lambda t: t, terrain)
        state = state.replace(terrain=terrain)
        stale = due & self.regenerator.stale(terrain, state.env.pipeline_state.task.tile)
        params = self.default_params(stale.shape[0]) if params is None else params
        episode = jax.tree.map(lambda x: jnp.where(stale, jnp.zeros_like(x), x), state.episode)
        totals = {**state.totals, "redraw_truncations": state.totals["redraw_truncations"] + jnp.sum(stale)}
        return self._reset_where(state.replace(episode=episode, totals=totals), stale, params)

    @property
    def observation_size(self) -> int:
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        return self.env.action_size

    def default_params(self, batch: int) -> EnvParams:
        """The env's default episode parameters for every env of a batch."""
        return self.env.default_params().repeat(batch)

    def reset(self, keys: jax.Array, params: EnvParams | None = None) -> BatchState:
        """Reset a batch (one key per env) with per-env ``params`` (default: the env's defaults)."""
        check_batch(self.env, keys.shape[0])
        batch = keys.shape[0]
        params = self.default_params(batch) if params is None else params
        terrain = None if self.regenerator is None else self.env.world.tiles
        env = self.env if terrain is None else self.env.with_terrain(terrain)
        env_state = jax.vmap(env.reset)(keys, params)
        zeros = jnp.zeros((batch,), jnp.float32)
        episode = EpisodeAccumulator(ret=zeros, length=zeros, terms={k: zeros for k in reward.TERM_NAMES})
        return BatchState(env=env_state, episode=episode, totals=_zero_totals(), terrain=terrain)

    def step(self, state: BatchState, actions: jax.Array, params: EnvParams | None = None) -> BatchState:
        """Step every env; reset the finished ones with ``params``; add finished episodes to the totals."""
        return self.step_with_final(state, actions, params)[0]

    def step_with_final(
        self, state: BatchState, actions: jax.Array, params: EnvParams | None = None, reset_metrics: bool = False
    ) -> tuple[BatchState, EnvState, EpisodeAccumulator]:
        """``step``, also returning what the auto-reset replaces.

        Returns (new batch state, every env's state after the step and before the auto-reset:
        the terminal state where it finished, the sums of the episode that step ended or
        continued). ``reset_metrics`` (static) also gives the reset envs their fresh episodes'
        metrics (zero rewards, no reasons, the new goal distance) instead of the terminal ones.
        """
        stepped, episode = self.advance(state, actions)
        params = self.default_params(actions.shape[0]) if params is None else params
        return self.reset_done(stepped, params, reset_metrics), stepped.env, episode

    def advance(self, state: BatchState, actions: jax.Array) -> tuple[BatchState, EpisodeAccumulator]:
        """Step every env without resetting: the state holding the stepped envs (finished ones still
        terminal, their running sums zeroed), and the sums of each env's episode up to this step."""
        nxt = jax.vmap(self.bound(state).step)(state.env, actions)
        done = nxt.done > 0
        episode = EpisodeAccumulator(
            ret=state.episode.ret + nxt.reward,
            length=state.episode.length + 1.0,
            terms={k: v + nxt.metrics[f"reward/{k}"] for k, v in state.episode.terms.items()},
        )
        totals = self._add_totals(state.totals, nxt, episode, done)

        def keep(x):
            return jnp.where(done, jnp.zeros_like(x), x)

        running = EpisodeAccumulator(
            ret=keep(episode.ret), length=keep(episode.length), terms={k: keep(v) for k, v in episode.terms.items()}
        )
        return BatchState(env=nxt, episode=running, totals=totals, terrain=state.terrain), episode

    def reset_done(self, state: BatchState, params: EnvParams, reset_metrics: bool = False) -> BatchState:
        """Replace the finished envs of an advanced state by fresh episodes drawn from their own keys
        with their ``params`` (skipped when none ended)."""
        return self._reset_where(state, state.env.done > 0, params, reset_metrics)

    def _reset_where(
        self, state: BatchState, done: jax.Array, params: EnvParams, reset_metrics: bool = False
    ) -> BatchState:
        """The envs where ``done`` replaced by fresh episodes drawn from their own keys (skipped when none)."""
        env = self.bound(state)

        def fresh(current: EnvState) -> EnvState:
            keys = jax.vmap(lambda k: jax.random.split(k)[1])(current.pipeline_state.task.rng)
            new = jax.vmap(env.reset)(keys, params)
            pick = per_env_picker(done)
            metrics = jax.tree.map(pick, new.metrics, current.metrics) if reset_metrics else current.metrics
            sim = select_sim(done, new.pipeline_state, current.pipeline_state)
            info = dict(current.info)  # truncation stays the step's; privileged inputs follow the observation
            if "privileged_obs" in info:
                info["privileged_obs"] = pick(new.info["privileged_obs"], info["privileged_obs"])
            return current.replace(pipeline_state=sim, obs=pick(new.obs, current.obs), metrics=metrics, info=info)

        return state.replace(env=jax.lax.cond(jnp.any(done), fresh, lambda s: s, state.env))

    @staticmethod
    def _add_totals(totals: dict, nxt: EnvState, episode: EpisodeAccumulator, done: jax.Array) -> dict:
        """Add the finished episodes (and per-step counters) to the running totals."""
        d = done.astype(jnp.float32)
        m = nxt.metrics
        add = {
            "episodes": jnp.sum(d),
            "return": jnp.sum(d * episode.ret),
            "length": jnp.sum(d * episode.length),
            "success": jnp.sum(d * m["termination/goal_reached"]),
            "final_distance": jnp.sum(d * m["distance_to_goal"]),
            "env_steps": jnp.asarray(done.shape[0], jnp.float32),
            "nonfinite_action": jnp.sum(m["nonfinite_action"]),
            "nonfinite_state": jnp.sum(m["termination/non_finite"]),
            # per env step, finished or not: what long episodes (corridor, spiral) show before they end
            "step_reward": jnp.sum(nxt.reward),
            "step_distance": jnp.sum(m["distance_to_goal"]),
            "step_checkpoint": jnp.sum(m["checkpoint_index"]),
        }
        add.update({f"reward/{k}": jnp.sum(d * v) for k, v in episode.terms.items()})
        ended = (*termination.REASONS, *termination.GROUPS)
        add.update({f"termination/{k}": jnp.sum(d * m[f"termination/{k}"]) for k in ended})
        return {**totals, **{k: totals[k] + add[k] for k in add}}

    def episode_ends(self, state: BatchState) -> EpisodeEnds:
        """What an advanced (not yet reset) batch tells the terrain curriculum: which episodes ended,
        which reached their goal, and the share of their start distance to the goal they covered."""
        env = state.env
        start = env.pipeline_state.task.start_distance  # measured as distance_to_goal is (reward.progress)
        progress = 1.0 - env.metrics["distance_to_goal"] / jnp.maximum(start, 1e-6)
        return EpisodeEnds(done=env.done, success=env.metrics["termination/goal_reached"], progress=progress)

    @staticmethod
    def env_keys(state: BatchState) -> jax.Array:
        """Every env's PRNG key of this step, (B, 2): the stream its next reset draws from (a caller
        folds in a salt of its own before drawing from it)."""
        return state.env.pipeline_state.task.rng

    def drain(self, state: BatchState) -> tuple[BatchState, dict[str, jax.Array]]:
        """Return the totals and the state with them zeroed (between jitted chunks)."""
        return state.replace(totals=jax.tree.map(jnp.zeros_like, state.totals)), dict(state.totals)


def per_env_picker(mask: jax.Array):
    """``pick(a, b)``: ``a`` where ``mask`` (one bool per env, the leading axis), else ``b``."""
    return lambda a, b: jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)


def select_sim(mask: jax.Array, a: SimState, b: SimState) -> SimState:
    """Per env, the simulator state of ``a`` where ``mask``, else of ``b`` (Warp's shared buffers kept)."""
    return SimState(
        physics=backend.select(mask, a.physics, b.physics), task=jax.tree.map(per_env_picker(mask), a.task, b.task)
    )


def check_batch(env: HSAEnv, batch: int) -> None:
    """Refuse a batch larger than a Warp env's shared contact buffer was sized for (``HSAEnv(num_envs=...)``)."""
    if env.physics_backend == "warp" and batch > env.num_envs:
        raise ValueError(
            f"a batch of {batch} envs on the Warp backend needs an env built for at least that many: "
            f"HSAEnv(config, num_envs={batch}) (this one shares its contact buffer among {env.num_envs})"
        )


def summarize(totals: dict[str, float], levels: int = 1) -> dict[str, float]:
    """Turn drained totals (host floats, summed over devices) into per-episode means and rates
    (and the terrain curriculum's levels, of ``levels``).

    Per-episode keys are left out when no episode ended in the period (rather than logged as 0).
    """
    out = {
        "episodes": totals["episodes"],
        "env_steps": totals["env_steps"],
        "nonfinite/actions": totals["nonfinite_action"],
        "nonfinite/states": totals["nonfinite_state"],
    }
    steps = max(totals["env_steps"], 1.0)
    out.update(
        {
            "step/reward": totals["step_reward"] / steps,
            "step/distance_to_goal": totals["step_distance"] / steps,
            "step/checkpoint_index": totals["step_checkpoint"] / steps,
        }
    )
    cut = totals.get("redraw_truncations", 0.0)
    if cut > 0:  # only with terrain re-draws shorter than an episode
        out["terrain/redraw_truncations"] = cut
        out["terrain/redraw_truncated_share"] = cut / (cut + totals["episodes"])  # of the episodes that ended
    out.update(terrain_curriculum.summarize(totals, levels))
    out.update(randomization_curriculum.summarize(totals))
    episodes = totals["episodes"]
    if episodes <= 0:
        return out
    out.update(
        {
            "episode/return": totals["return"] / episodes,
            "episode/length": totals["length"] / episodes,
            "episode/success_rate": totals["success"] / episodes,
            "episode/final_distance": totals["final_distance"] / episodes,
        }
    )
    for key, value in totals.items():
        if key.startswith("reward/"):
            out[f"episode/{key}"] = value / episodes
        elif key.startswith("termination/"):
            out[key] = value / episodes
    return out

"""FastTD3 on the batched hsa_mjx env: thousands of envs each step once with their own exploration noise,
the steps go to a replay buffer on the device, then several n-step updates follow (``td3.updates_per_step``).

The same shape as the PPO learner (``train.learners.ppo.learner``), so the collection strategies, the
trainer, checkpoints and curricula use it unchanged: pure :meth:`TD3Learner.reset` and
:meth:`TD3Learner.epoch` over a loop state the caller owns (here it also holds the replay buffer and each
env's noise scale: a checkpoint holds the learner state alone, and a resumed run refills its buffer).
"""

from __future__ import annotations

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before Brax imports it)

# isort: split
import jax
import jax.numpy as jnp
from brax.training.acme import running_statistics
from flax import struct

from hsa_mjx.batch.auto_reset import AutoResetEnv, BatchState
from hsa_mjx.curricula import goal_curriculum
from hsa_mjx.curricula.state import Curricula, CurriculumRules, EnvLevels
from hsa_mjx.task.env import HSAEnv

from ..ppo.learner import AXIS, REGENERATION_SALT, start
from ..ppo.networks import network_obs
from . import replay
from .networks import TD3State, act, init_state, make_networks, privileged_size
from .update import TD3Update

NOISE_SALT = 0x7D3  # folded into an env's key for its exploration noise scale


@struct.dataclass
class TD3LoopState:
    """What the training loop carries besides the learner: the env batch, the curricula, the replay
    buffer and each env's exploration noise scale."""

    envs: BatchState
    curricula: Curricula
    buffer: replay.ReplayBuffer
    noise: jax.Array  # (envs,)


class TD3Learner:
    """TD3's collection and learning for one config (``run.learner: td3``).

    Args:
        config: the training config.
        env: the single-env :class:`HSAEnv` built for the batch each device steps.
        axis: the device axis gradients and statistics are reduced over (None: one device).
    """

    def __init__(self, config, env: HSAEnv, axis: str | None = AXIS):
        self.config, self.env, self.axis, td3 = config, env, axis, config.td3
        self.batch_env = AutoResetEnv(env, config.run.regenerate_terrain_every)
        self.rules = CurriculumRules(
            config.env, config.goal_curriculum, config.terrain_curriculum, config.randomization_curriculum
        )
        self.privileged = td3.privileged_critic
        if self.privileged and not env.privileged:
            raise ValueError("td3.privileged_critic needs an env built with HSAEnv(..., privileged=True)")
        self.networks = make_networks(td3, env.observation_size, env.action_size)
        self.network_input_size = env.observation_size + privileged_size(config)
        self.devices = config.run.num_envs // env.num_envs  # every process's devices
        self.capacity = max(td3.buffer_size // env.num_envs, td3.n_step + 1)
        self.batch_per_device = max(td3.batch_size // self.devices, 1)
        self.iterations_per_epoch = max(1, config.run.steps_per_epoch // config.env_steps_per_iteration)
        self.update = TD3Update(self.networks, td3, axis)

    @property
    def env_steps_per_epoch(self) -> int:
        """Env steps (all devices) one epoch advances."""
        return self.iterations_per_epoch * self.config.env_steps_per_iteration

    def init_state(self, key: jax.Array) -> TD3State:
        """A fresh learner state."""
        return init_state(self.config.td3, self.networks, key, self.network_input_size)

    def _sum_over_devices(self, x):
        return x if self.axis is None else jax.lax.psum(x, self.axis)

    def _every_devices_envs(self, x: jax.Array) -> jax.Array:
        """(steps, envs of this device) -> (steps, envs of every device)."""
        return x if self.axis is None else jax.lax.all_gather(x, self.axis, axis=1, tiled=True)

    def _noise_scales(self, keys: jax.Array) -> jax.Array:
        td3 = self.config.td3
        draw = jax.vmap(lambda k: jax.random.uniform(jax.random.fold_in(k, NOISE_SALT)))(keys)
        return td3.noise_std_min + (td3.noise_std_max - td3.noise_std_min) * draw

    def reset(
        self,
        keys: jax.Array,
        goal: goal_curriculum.GoalCurriculumState,
        levels: EnvLevels | None,
        batch_env: AutoResetEnv | None = None,
    ) -> TD3LoopState:
        """One device's fresh envs on the curricula's start (or restored) state, an empty buffer."""
        envs, curricula = start(self.config, self.rules, batch_env or self.batch_env, keys, goal, levels)
        obs = network_obs(envs.env, self.privileged)
        n = obs.shape[0]
        example = replay.Transition(
            obs=obs,
            action=jnp.zeros((n, self.env.action_size)),
            reward=jnp.zeros((n,)),
            next_obs=obs,
            ended=jnp.zeros((n,)),
            terminal=jnp.zeros((n,)),
        )
        buffer = replay.init(self.capacity, example)
        return TD3LoopState(envs=envs, curricula=curricula, buffer=buffer, noise=self._noise_scales(keys))

    def env_step(self, ts: TD3State, state: TD3LoopState, key: jax.Array) -> tuple[TD3LoopState, dict]:
        """Every env one step under the actor with its own noise; the step into the buffer; the ended
        envs reset (the terrain curriculum moves them first) with a new noise scale."""
        batch_env, rules = self.batch_env, self.rules
        obs = network_obs(state.envs.env, self.privileged)
        action = act(self.networks, ts.params.actor, ts.normalizer, obs)
        noise = state.noise[:, None] * jax.random.normal(key, action.shape)
        action = jnp.clip(action + noise, -1.0, 1.0)
        stepped, _ = batch_env.advance(state.envs, action)
        ended = stepped.env.done
        truncated = stepped.env.info["truncation"]
        transition = replay.Transition(
            obs=obs,
            action=action,
            reward=stepped.env.reward,
            next_obs=network_obs(stepped.env, self.privileged),  # before the reset: the episode's true last input
            ended=ended,
            terminal=ended * (1.0 - truncated),
        )
        curricula = rules.after_step(state.curricula, batch_env.episode_ends(stepped), batch_env.env_keys(stepped))
        envs = batch_env.reset_done(stepped, rules.params(curricula))
        fresh = self._noise_scales(batch_env.env_keys(stepped))
        noise_scale = jnp.where(ended > 0, fresh, state.noise)
        buffer = replay.add(state.buffer, transition)
        outcomes = {"obs": obs, "ended": ended, "goal_reached": stepped.env.metrics["termination/goal_reached"]}
        return TD3LoopState(envs=envs, curricula=curricula, buffer=buffer, noise=noise_scale), outcomes

    def learn(self, ts: TD3State, state: TD3LoopState, obs: jax.Array, key: jax.Array) -> tuple[TD3State, dict]:
        """Observation statistics from the step's inputs ``obs``, then ``updates_per_step`` updates once every env
        has ``learning_starts`` steps in the buffer (before that the state stays, no metrics count)."""
        td3 = self.config.td3
        normalizer = ts.normalizer
        if td3.normalize_observations:
            finite = jnp.all(jnp.isfinite(obs), axis=-1)
            normalizer = running_statistics.update(
                normalizer,
                jnp.where(finite[:, None], obs, 0.0),
                weights=finite.astype(jnp.float32),
                std_min_value=td3.observation_std_min,
                pmap_axis_name=self.axis,
            )
        ts = ts.replace(normalizer=normalizer)
        ready = state.buffer.filled >= td3.learning_starts

        def one(ts, k):
            k_sample, k_update = jax.random.split(k)
            batch = replay.sample(state.buffer, k_sample, self.batch_per_device, td3.n_step, td3.discounting)
            ts, metrics = self.update.step(ts, batch, k_update)
            return ts, {**metrics, "buffer_age": jnp.mean(batch.age)}

        def updates(ts):
            ts, metrics = jax.lax.scan(one, ts, jax.random.split(key, td3.updates_per_step))
            return ts, {k: jnp.nanmean(v) for k, v in metrics.items()}

        shapes = jax.eval_shape(updates, ts)[1]
        skipped = {k: jnp.full(v.shape, jnp.nan, v.dtype) for k, v in shapes.items()}
        return jax.lax.cond(ready, updates, lambda ts: (ts, skipped), ts)

    def _iteration(self, carry, _):
        ts, state, key = carry
        key, k_step, k_learn = jax.random.split(key, 3)
        state, outcomes = self.env_step(ts, state, k_step)
        ts, metrics = self.learn(ts, state, outcomes["obs"], k_learn)
        if self.config.goal_curriculum.enabled:
            done = self._every_devices_envs(outcomes["ended"][None]) > 0
            success = self._every_devices_envs(outcomes["goal_reached"][None]) > 0
            goal = self.rules.after_collection(state.curricula.goal, success, done)
            state = state.replace(curricula=state.curricula.replace(goal=goal))
        return (ts, state, key), metrics

    def drain(self, state: TD3LoopState, batch_env: AutoResetEnv | None = None) -> tuple[TD3LoopState, dict]:
        """This device's episode totals and the curricula's per-cell sums since the last drain; both zeroed."""
        envs, totals = (batch_env or self.batch_env).drain(state.envs)
        curricula, cell_totals = self.rules.drain(state.curricula)
        return state.replace(envs=envs, curricula=curricula), {**totals, **cell_totals}

    def epoch(self, ts: TD3State, state: TD3LoopState, key: jax.Array):
        """``iterations_per_epoch`` env steps, each followed by its updates; returns (ts, state,
        {"totals": episode totals summed over devices, "losses": the updates' mean diagnostics})."""
        (ts, state, _), metrics = jax.lax.scan(
            self._iteration, (ts, state, key), None, length=self.iterations_per_epoch
        )
        steps = state.envs.env.pipeline_state.task.step_count
        envs = self.batch_env.tick(
            state.envs, jax.random.fold_in(key, REGENERATION_SALT), self.rules.params(state.curricula)
        )
        cut = (envs.env.pipeline_state.task.step_count == 0) & (steps > 0)  # episodes a terrain re-draw restarted
        state = state.replace(envs=envs, buffer=replay.end_newest(state.buffer, cut))
        state, totals = self.drain(state)
        losses = {k: jnp.nanmean(v) for k, v in metrics.items()}
        losses["buffer_size"] = self._sum_over_devices(state.buffer.filled * self.env.num_envs).astype(jnp.float32)
        losses["noise_std_mean"] = jnp.mean(state.noise)
        losses["updates_per_env_step"] = jnp.asarray(float(self.config.td3.updates_per_step))
        return ts, state, {"totals": self._sum_over_devices(totals), "losses": losses}

    def collect_epoch(self, ts: TD3State, state: TD3LoopState, key: jax.Array):
        """The epoch's env steps alone, no learning (for timing the update's share)."""

        def one(carry, _):
            state, key = carry
            key, k_step, _ = jax.random.split(key, 3)
            state, _ = self.env_step(ts, state, k_step)
            return (state, key), None

        (state, _), _ = jax.lax.scan(one, (state, key), None, length=self.iterations_per_epoch)
        return ts, state

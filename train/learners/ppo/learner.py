"""PPO on the batched hsa_mjx env, built from Brax's PPO networks and GAE.

Brax's ``ppo.train`` owns its training state and env state inside one function, so a checkpoint
there holds neither the optimiser state nor the step count, and the env state (where the curricula
live) never reaches a callback. This learner keeps Brax's PPO networks, GAE and running observation
statistics, with the loss and gradient step of ``train.learners.ppo.update``, as pure functions of
pytrees the caller owns: :meth:`PPOLearner.collect` (policy and env steps, with the terrain
curriculum) and :meth:`PPOLearner.learn` (observation statistics, goal curriculum, SGD), and the
epoch built from them. How devices share the work is not its business: a collection strategy
(``train.devices.strategies``) places and calls these functions on one device, under ``pmap``, or
one thread per GPU. Every reduction over devices names the learner's ``axis``; with ``axis=None``
(one device) there is none.
"""

from __future__ import annotations

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before Brax imports it)

# isort: split
import functools
from typing import Any

import jax
import jax.numpy as jnp
from brax.training import types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import networks as ppo_networks
from flax import struct

from hsa_mjx.batch.auto_reset import AutoResetEnv, BatchState
from hsa_mjx.curricula import goal_curriculum
from hsa_mjx.curricula.state import Curricula, CurriculumRules, EnvLevels
from hsa_mjx.task.env import HSAEnv

from ...config import TrainConfig
from .networks import TrainingState, init_training_state, make_networks, network_obs
from .update import PPOUpdate, explained_variance, with_targets

REGENERATION_SALT = 0x7E77  # folded into an iteration's collection key for its terrain re-draw
PHASE_SALT = 0x9A5E  # folded into an env's key for its first episode's random phase (run.random_initial_phase)
AXIS = "devices"  # the name every reduction over devices uses (pmap's axis, or one thread per GPU's learning step)


def with_random_phase(envs: BatchState, keys: jax.Array, max_steps: int) -> BatchState:
    """Every env's episode already ``randint(0, max_steps)`` steps old (legged_gym's random episode phase):
    the first episodes are truncated at different steps, so the batch's episodes never end in lockstep."""
    steps = jax.vmap(lambda k: jax.random.randint(jax.random.fold_in(k, PHASE_SALT), (), 0, max_steps))(keys)
    task = envs.env.pipeline_state.task.replace(step_count=steps.astype(jnp.int32))
    return envs.replace(env=envs.env.replace(pipeline_state=envs.env.pipeline_state.replace(task=task)))


def start(
    config: TrainConfig,
    rules: CurriculumRules,
    batch_env: AutoResetEnv,
    keys: jax.Array,
    goal: goal_curriculum.GoalCurriculumState,
    levels: EnvLevels | None,
) -> tuple[BatchState, Curricula]:
    """One device's fresh envs (one key each) and curricula from the goal curriculum and, when given,
    every env's levels; with ``run.random_initial_phase`` each first episode starts at a random step."""
    curricula = rules.init(keys, goal, levels)
    envs = batch_env.reset(keys, rules.params(curricula))
    if config.run.random_initial_phase:
        envs = with_random_phase(envs, keys, config.env.termination.max_episode_steps)
    return envs, curricula


@struct.dataclass
class LoopState:
    """What the training loop carries besides the learner: the env batch and the curricula it owns."""

    envs: BatchState
    curricula: Curricula


class PPOLearner:
    """PPO's collection and learning steps for one config.

    Args:
        config: the training config.
        env: the single-env :class:`HSAEnv` built from ``config.env`` (its observation and action
            sizes; a strategy may build one env copy per device for the collection).
        axis: the name of the device axis the reductions run over (None: one device, none).
    """

    def __init__(self, config: TrainConfig, env: HSAEnv, axis: str | None = AXIS):
        self.config, self.env, self.axis = config, env, axis
        # the goal curriculum learns from each collection's outcomes in ``learn`` (gathered over devices),
        # the terrain curriculum from each step's episode ends, before those envs reset
        self.batch_env = AutoResetEnv(env, config.run.regenerate_terrain_every)
        self.rules = CurriculumRules(
            config.env, config.goal_curriculum, config.terrain_curriculum, config.randomization_curriculum
        )
        self.privileged = config.ppo.privileged_critic
        if self.privileged and not env.privileged:
            raise ValueError("ppo.privileged_critic needs an env built with HSAEnv(..., privileged=True)")
        self.networks = make_networks(config, env.observation_size, env.action_size, env.privileged_size)
        self.network_input_size = env.observation_size + env.privileged_size
        self.make_policy = ppo_networks.make_inference_fn(self.networks)
        ppo = config.ppo
        self.unrolls_per_iteration = ppo.batch_size * ppo.num_minibatches // config.run.num_envs
        self.iterations_per_epoch = max(1, config.run.steps_per_epoch // config.env_steps_per_iteration)
        self.update = PPOUpdate(self.networks, ppo, axis)

    def init_state(self, key: jax.Array) -> TrainingState:
        """A fresh learner state."""
        return init_training_state(self.config, self.networks, key, self.network_input_size)

    @property
    def env_steps_per_epoch(self) -> int:
        """Env steps (all devices) one epoch advances."""
        return self.iterations_per_epoch * self.config.env_steps_per_iteration

    # ----- reductions over devices ----------------------------------------------------------
    def _sum_over_devices(self, x: Any) -> Any:
        return x if self.axis is None else jax.lax.psum(x, self.axis)

    def _every_devices_envs(self, x: jax.Array) -> jax.Array:
        """(steps, envs of this device) -> (steps, envs of every device), device order."""
        return x if self.axis is None else jax.lax.all_gather(x, self.axis, axis=1, tiled=True)

    # ----- collection -----------------------------------------------------------------------
    def reset(
        self,
        keys: jax.Array,
        goal: goal_curriculum.GoalCurriculumState,
        levels: EnvLevels | None,
        batch_env: AutoResetEnv | None = None,
    ) -> LoopState:
        """One device's fresh envs (one key each) on the curricula's start (or restored) state; with
        ``run.random_initial_phase`` each first episode starts at a random step of its length."""
        envs, curricula = start(self.config, self.rules, batch_env or self.batch_env, keys, goal, levels)
        return LoopState(envs=envs, curricula=curricula)

    def unroll(
        self, ts: TrainingState, state: LoopState, key: jax.Array, batch_env: AutoResetEnv | None = None
    ) -> tuple[LoopState, types.Transition]:
        """``unroll_length`` steps of every env under the current stochastic policy; the terrain
        curriculum moves the envs whose episode ended before they reset."""
        batch_env, rules = batch_env or self.batch_env, self.rules
        policy = self.make_policy((ts.normalizer, ts.params.policy))

        def step(carry, _):
            loop, k = carry
            k, k_act = jax.random.split(k)
            obs = network_obs(loop.envs.env, self.privileged)
            actions, extras = policy(obs, k_act)
            stepped, _ = batch_env.advance(loop.envs, actions)
            # the terrain curriculum draws from each env's own key of this step (with a salt of its own)
            ends, env_keys = batch_env.episode_ends(stepped), batch_env.env_keys(stepped)
            curricula = rules.after_step(loop.curricula, ends, env_keys)
            ns = batch_env.reset_done(stepped, rules.params(curricula))
            state_extras = {
                "truncation": ns.env.info["truncation"],
                "episode_done": ns.env.done,
                "goal_reached": ns.env.metrics["termination/goal_reached"],
            }
            transition = types.Transition(
                observation=obs,
                action=actions,
                reward=ns.env.reward,
                discount=1.0 - ns.env.done,
                next_observation=network_obs(ns.env, self.privileged),
                extras={"policy_extras": extras, "state_extras": state_extras},
            )
            return (LoopState(envs=ns, curricula=curricula), k), transition

        (state, _), data = jax.lax.scan(step, (state, key), None, length=self.config.ppo.unroll_length)
        return state, data

    def collect(
        self, ts: TrainingState, state: LoopState, key: jax.Array, batch_env: AutoResetEnv | None = None
    ) -> tuple[LoopState, types.Transition]:
        """Several unrolls, reshaped to (sequences, unroll_length, ...), sequences unroll-major."""

        def one(carry, _):
            s, k = carry
            k, k_unroll = jax.random.split(k)
            s, data = self.unroll(ts, s, k_unroll, batch_env)
            return (s, k), data

        (state, _), data = jax.lax.scan(one, (state, key), None, length=self.unrolls_per_iteration)
        regeneration_key = jax.random.fold_in(key, REGENERATION_SALT)
        envs = (batch_env or self.batch_env).tick(state.envs, regeneration_key, self.rules.params(state.curricula))
        state = state.replace(envs=envs)  # fresh terrain tiles when due (run.regenerate_terrain_every)
        # (unrolls, T, B, ...) -> (unrolls * B, T, ...)
        data = jax.tree.map(lambda x: jnp.swapaxes(x, 1, 2), data)
        return state, jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), data)

    def drain(self, state: LoopState, batch_env: AutoResetEnv | None = None) -> tuple[LoopState, dict]:
        """This device's episode totals and the curricula's per-cell sums since the last drain; both zeroed."""
        envs, totals = (batch_env or self.batch_env).drain(state.envs)
        curricula, cell_totals = self.rules.drain(state.curricula)
        return LoopState(envs=envs, curricula=curricula), {**totals, **cell_totals}

    # ----- learning -------------------------------------------------------------------------
    def _minibatch_step(self, carry, minibatch: types.Transition):
        """One gradient step; a non-finite loss leaves parameters and optimiser untouched."""
        params, opt_state, normalizer, key, skipped = carry
        key, k_loss = jax.random.split(key)
        loss, metrics, new_params, new_opt = self.update.step(params, opt_state, normalizer, minibatch, k_loss)
        bad = self._sum_over_devices(jnp.logical_not(jnp.isfinite(loss)).astype(jnp.int32)) > 0

        def keep(old, new):
            return jax.tree.map(lambda a, b: jnp.where(bad, a, b), old, new)

        return (
            keep(params, new_params),
            keep(opt_state, new_opt),
            normalizer,
            key,
            skipped + bad.astype(jnp.float32),
        ), metrics

    def _sgd_pass(self, carry, _, data: types.Transition):
        """One pass over the collected data in shuffled minibatches."""
        params, opt_state, normalizer, key, skipped = carry
        key, k_perm = jax.random.split(key)
        n_mb = self.config.ppo.num_minibatches
        perm = jax.random.permutation(k_perm, data.reward.shape[0])
        shuffled = jax.tree.map(lambda x: x[perm].reshape((n_mb, -1) + x.shape[1:]), data)
        carry, metrics = jax.lax.scan(self._minibatch_step, (params, opt_state, normalizer, key, skipped), shuffled)
        return carry, metrics

    def _goal_curriculum(
        self, goal: goal_curriculum.GoalCurriculumState, data: types.Transition
    ) -> goal_curriculum.GoalCurriculumState:
        """Feed the collection's episode ends to the goal curriculum in step order, all devices' envs per step.

        The same sequence of updates as one update per env step with outcomes gathered over the
        devices; only the goals of episodes that start during the collection use the range from its
        start (a lag of at most ``unroll_length x unrolls`` steps, see docs/training.md).
        """
        if not self.config.goal_curriculum.enabled:
            return goal
        unrolls, length = self.unrolls_per_iteration, self.config.ppo.unroll_length

        def step_major(x: jax.Array) -> jax.Array:  # (unrolls * B, T) -> (unrolls * T, B)
            x = jnp.swapaxes(x.reshape((unrolls, -1, length)), 1, 2)
            return self._every_devices_envs(x.reshape((unrolls * length, -1)))

        extras = data.extras["state_extras"]
        done, success = step_major(extras["episode_done"]) > 0, step_major(extras["goal_reached"]) > 0
        return self.rules.after_collection(goal, success, done)

    def learn(
        self, ts: TrainingState, goal: goal_curriculum.GoalCurriculumState, data: types.Transition, key: jax.Array
    ) -> tuple[TrainingState, goal_curriculum.GoalCurriculumState, dict]:
        """Observation statistics, goal curriculum, the collection's value targets and advantages (from the
        critic that collected it), then ``num_updates_per_batch`` SGD passes over ``data``."""
        obs = data.observation.reshape((-1, data.observation.shape[-1]))
        finite = jnp.all(jnp.isfinite(obs), axis=-1)
        normalizer = ts.normalizer
        if self.config.ppo.normalize_observations:
            normalizer = running_statistics.update(
                normalizer,
                jnp.where(finite[:, None], obs, 0.0),
                weights=finite.astype(jnp.float32),
                std_min_value=self.config.ppo.observation_std_min,
                pmap_axis_name=self.axis,
            )
        targets = self.update.targets(ts.params, normalizer, data)
        data = with_targets(data, targets)
        carry = (ts.params, ts.optimizer_state, normalizer, key, jnp.zeros(()))
        (params, opt_state, _, _, skipped), metrics = jax.lax.scan(
            functools.partial(self._sgd_pass, data=data), carry, None, length=self.config.ppo.num_updates_per_batch
        )
        metrics = jax.tree.map(jnp.mean, metrics)
        metrics["skipped_updates"] = skipped
        metrics["explained_variance"] = explained_variance(targets)
        return TrainingState(params, opt_state, normalizer), self._goal_curriculum(goal, data), metrics

    # ----- the epoch on one device (a strategy maps it over several) --------------------------
    def _iteration(self, carry, _):
        """Collect, then learn from the collection; new episodes see the updated goal curriculum."""
        ts, state, key = carry
        key, k_collect, k_sgd = jax.random.split(key, 3)
        state, data = self.collect(ts, state, k_collect)
        ts, goal, metrics = self.learn(ts, state.curricula.goal, data, k_sgd)
        return (ts, state.replace(curricula=state.curricula.replace(goal=goal)), key), metrics

    def epoch(self, ts: TrainingState, state: LoopState, key: jax.Array):
        """``iterations_per_epoch`` PPO iterations; returns (ts, state, {"totals": the drained episode
        totals summed over devices, "losses": mean losses})."""
        (ts, state, _), metrics = jax.lax.scan(
            self._iteration, (ts, state, key), None, length=self.iterations_per_epoch
        )
        state, totals = self.drain(state)
        return ts, state, {"totals": self._sum_over_devices(totals), "losses": jax.tree.map(jnp.mean, metrics)}

    def collect_epoch(self, ts: TrainingState, state: LoopState, key: jax.Array) -> tuple[TrainingState, LoopState]:
        """``iterations_per_epoch`` collections with the same keys as :meth:`epoch`, without learning
        (for timing the update's share of an epoch)."""

        def one(carry, _):
            state, key = carry
            key, k_collect, _ = jax.random.split(key, 3)
            state, data = self.collect(ts, state, k_collect)
            return (state, key), sum(jnp.sum(x) for x in jax.tree.leaves(data))  # keep every output live

        (state, _), _ = jax.lax.scan(one, (state, key), None, length=self.iterations_per_epoch)
        return ts, state

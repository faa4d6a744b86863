"""PPO on the batched hsa_mjx env, built from Brax's PPO networks, loss and gradient update.

Brax's ``ppo.train`` owns its training state and env state inside one function, so a checkpoint
there holds neither the optimiser state nor the step count, and the env state (where our
curriculum lives) never reaches a callback. This module keeps Brax's PPO pieces
(``ppo.networks``, ``ppo.losses.compute_ppo_loss``, ``gradients.gradient_update_fn``, running
observation statistics) and exposes one jitted, ``pmap``-ed training epoch whose whole state is a
pytree the caller can save and restore. Multi-device: the batch of envs is split over local
devices; gradients, observation statistics and curriculum outcomes are reduced over them. The
epoch is built from two pure pieces, ``_collect`` (policy and env steps) and ``_learn``
(statistics, curriculum, SGD); ``train/per_device.py`` runs the same pieces with the collection
jitted per GPU (``run.multi_device``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from brax.training import gradients, types
from brax.training import networks as brax_networks
from brax.training.acme import running_statistics
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks
from flax import linen, struct

from hsa_mjx.batch.auto_reset import AutoResetEnv, BatchState
from hsa_mjx.curricula import goal as cur
from hsa_mjx.curricula import terrain as tcur
from hsa_mjx.curricula.state import Curricula, CurriculumRules
from hsa_mjx.deploy import policy as pol
from hsa_mjx.task import privileged
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.task.types import EnvState
from train import compat
from train.config import TrainConfig

AXIS = "devices"
# the activations the exported numpy policy can run, as flax functions of the same names
ACTIVATIONS: dict[str, Callable] = {name: getattr(linen, name) for name in pol.ACTIVATIONS}


@struct.dataclass
class LoopState:
    """What the training loop carries besides the learner: the env batch and the curricula it owns."""

    envs: BatchState
    curricula: Curricula


@struct.dataclass
class TrainingState:
    """Learner state: network parameters, optimiser state, observation statistics."""

    params: ppo_losses.PPONetworkParams
    optimizer_state: optax.OptState
    normalizer: running_statistics.RunningStatisticsState


def make_networks(
    config: TrainConfig, observation_size: int, action_size: int, privileged_size: int = 0
) -> ppo_networks.PPONetworks:
    """Brax PPO actor and critic MLPs with the configured sizes.

    With ``privileged_size`` > 0 (``ppo.privileged_critic``) the networks' input is the policy's
    observation followed by the privileged values: the value network reads all of it, the policy
    only its first ``observation_size`` values (it also accepts the observation alone, as evaluation
    and export give it).
    """
    ppo = config.ppo
    normalize = types.identity_observation_preprocessor
    if ppo.normalize_observations:
        normalize = functools.partial(running_statistics.normalize, max_abs_value=ppo.observation_clip or None)
    actor_normalize = normalize if privileged_size == 0 else _actor_view(normalize, observation_size)
    networks = ppo_networks.make_ppo_networks(  # the policy's parameters are sized for the observation alone
        observation_size,
        action_size,
        preprocess_observations_fn=actor_normalize,
        policy_hidden_layer_sizes=ppo.policy_hidden_sizes,
        value_hidden_layer_sizes=ppo.value_hidden_sizes,
        activation=ACTIVATIONS[ppo.activation],
        init_noise_std=ppo.init_noise_std,
        distribution_type=ppo.distribution_type,
        noise_std_type=ppo.noise_std_type,
    )
    if privileged_size == 0:
        return networks
    value = brax_networks.make_value_network(
        observation_size + privileged_size,
        preprocess_observations_fn=normalize,
        hidden_layer_sizes=ppo.value_hidden_sizes,
        activation=ACTIVATIONS[ppo.activation],
    )
    return networks.replace(value_network=value)


def _actor_view(normalize: Callable, actor_size: int) -> Callable:
    """The policy's preprocessing under a privileged critic: normalise, then keep the actor's values."""

    def preprocess(obs: jax.Array, stats: running_statistics.RunningStatisticsState) -> jax.Array:
        if obs.shape[-1] == actor_size:  # the policy's observation alone
            return normalize(obs, stats.replace(mean=stats.mean[:actor_size], std=stats.std[:actor_size]))
        return normalize(obs, stats)[..., :actor_size]

    return preprocess


def privileged_size(config: TrainConfig) -> int:
    """Privileged inputs the networks read after the observation (0 without ``ppo.privileged_critic``)."""
    return privileged.size(config.env.observation) if config.ppo.privileged_critic else 0


def network_obs(state: EnvState, privileged: bool) -> jax.Array:
    """What the networks read from an env state: the observation, then the privileged inputs when used."""
    if not privileged:
        return state.obs
    return jnp.concatenate([state.obs, state.info["privileged_obs"]], axis=-1)


def make_optimizer(config: TrainConfig) -> optax.GradientTransformation:
    """Adam with global-norm gradient clipping."""
    return optax.chain(optax.clip_by_global_norm(config.ppo.max_grad_norm), optax.adam(config.ppo.learning_rate))


def init_training_state(
    config: TrainConfig, networks: ppo_networks.PPONetworks, key: jax.Array, observation_size: int
) -> TrainingState:
    """Fresh parameters, optimiser and normaliser state (unreplicated)."""
    k_policy, k_value = jax.random.split(key)
    params = ppo_losses.PPONetworkParams(
        policy=networks.policy_network.init(k_policy), value=networks.value_network.init(k_value)
    )
    normalizer = running_statistics.init_state(jax.ShapeDtypeStruct((observation_size,), jnp.float32))
    return TrainingState(params=params, optimizer_state=make_optimizer(config).init(params), normalizer=normalizer)


class PPOLearner:
    """Builds the pmapped reset and training-epoch functions for one config.

    Args:
        config: the training config.
        env: the single-env :class:`HSAEnv` built from ``config.env``.
        num_devices: local devices to split the envs over.
    """

    def __init__(self, config: TrainConfig, env: HSAEnv, num_devices: int):
        self.config, self.env, self.num_devices = config, env, num_devices
        # the goal curriculum learns from each collection's outcomes in ``_learn`` (gathered over devices),
        # the terrain curriculum from each step's episode ends, before those envs reset
        self.batch_env = AutoResetEnv(env)
        self.rules = CurriculumRules(env, config.curriculum, config.terrain_curriculum)
        self.privileged = config.ppo.privileged_critic
        if self.privileged and not env.privileged:
            raise ValueError("ppo.privileged_critic needs an env built with HSAEnv(..., privileged=True)")
        self.networks = make_networks(config, env.observation_size, env.action_size, env.privileged_size)
        self.network_input_size = env.observation_size + env.privileged_size
        self.make_policy = ppo_networks.make_inference_fn(self.networks)
        self.optimizer = make_optimizer(config)
        ppo = config.ppo
        self.envs_per_device = config.run.num_envs // num_devices
        if env.num_envs != self.envs_per_device:
            raise ValueError(
                f"the env is built for batches of {env.num_envs}, but each of the {num_devices} devices "
                f"steps {self.envs_per_device} envs (run.num_envs {config.run.num_envs}): build it with "
                f"HSAEnv(config.env, num_envs={self.envs_per_device}) (train.per_device.make_learner does)"
            )
        self.unrolls_per_iteration = ppo.batch_size * ppo.num_minibatches // config.run.num_envs
        self.iterations_per_epoch = max(1, config.run.steps_per_epoch // config.env_steps_per_iteration)
        self.loss_fn = functools.partial(
            ppo_losses.compute_ppo_loss,
            ppo_network=self.networks,
            entropy_cost=ppo.entropy_cost,
            discounting=ppo.discounting,
            reward_scaling=ppo.reward_scaling,
            gae_lambda=ppo.gae_lambda,
            clipping_epsilon=ppo.clipping_epsilon,
            normalize_advantage=ppo.normalize_advantage,
            vf_coefficient=ppo.vf_loss_coefficient,
        )
        self.update_fn = gradients.gradient_update_fn(self.loss_fn, self.optimizer, pmap_axis_name=AXIS, has_aux=True)
        self.reset_fn = jax.pmap(
            functools.partial(self._reset, batch_env=self.batch_env, rules=self.rules), axis_name=AXIS
        )
        self.epoch_fn = jax.pmap(self._epoch, axis_name=AXIS, donate_argnums=(0, 1))
        self.collect_epoch_fn = jax.pmap(self._collect_epoch, axis_name=AXIS)

    @staticmethod
    def _reset(
        keys: jax.Array,
        goal: cur.CurriculumState,
        levels: tcur.TerrainLevels | None,
        batch_env: AutoResetEnv,
        rules: CurriculumRules,
    ) -> LoopState:
        """One device's fresh envs on the curricula's start (or restored) state."""
        curricula = rules.init(keys, goal, levels)
        return LoopState(envs=batch_env.reset(keys, rules.params(curricula)), curricula=curricula)

    def reset(
        self, env_keys: jax.Array, curriculum: cur.CurriculumState, terrain: tcur.TerrainLevels | None = None
    ) -> LoopState:
        """Fresh envs (``env_keys``: (devices, envs per device, 2)) starting from ``curriculum`` (unreplicated)
        and, when given, the terrain levels of every env ((envs,) arrays in device order; resume)."""
        devices = jax.local_devices()[: env_keys.shape[0]]
        if terrain is not None:
            terrain = jax.tree.map(lambda x: jnp.reshape(x, env_keys.shape[:2]), terrain)
        return self.reset_fn(jax.device_put(env_keys), replicate(curriculum, devices), terrain)

    def terrain_levels(self, state: LoopState) -> dict:
        """This process's envs' terrain type rows and levels as host arrays (envs,), in device order."""
        return tcur.to_host([jax.device_get(state.curricula.terrain)])

    @staticmethod
    def goal_curriculum(state: LoopState) -> cur.CurriculumState:
        """The goal curriculum's state (the first device's copy; all are equal)."""
        return jax.tree.map(lambda x: x[0], state.curricula.goal)

    def epoch(self, ts: TrainingState, state: LoopState, keys: jax.Array):
        """``iterations_per_epoch`` PPO iterations on every device (one key per device); returns
        (ts, state, {"totals": episode totals summed over devices, "losses": mean losses per device})."""
        return self.epoch_fn(ts, state, keys)

    def collect_epoch(self, ts: TrainingState, state: LoopState, keys: jax.Array):
        """The epoch's collections alone, no learning (for timing the update's share)."""
        return self.collect_epoch_fn(ts, state, keys)

    @property
    def env_steps_per_epoch(self) -> int:
        """Env steps (all devices) one call of ``epoch`` advances."""
        return self.iterations_per_epoch * self.config.env_steps_per_iteration

    # ----- rollout ------------------------------------------------------------------------
    def _unroll(
        self, ts: TrainingState, state: LoopState, key: jax.Array, batch_env: AutoResetEnv, rules: CurriculumRules
    ) -> tuple[LoopState, types.Transition]:
        """``unroll_length`` steps of every env under the current stochastic policy; the terrain
        curriculum moves the envs whose episode ended before they reset."""
        policy = self.make_policy((ts.normalizer, ts.params.policy))

        def step(carry, _):
            loop, k = carry
            k, k_act = jax.random.split(k)
            obs = network_obs(loop.envs.env, self.privileged)
            actions, extras = policy(obs, k_act)
            stepped, _ = batch_env.advance(loop.envs, actions)
            curricula = rules.after_step(loop.curricula, stepped.env)
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

    def _collect(
        self,
        ts: TrainingState,
        state: LoopState,
        key: jax.Array,
        batch_env: AutoResetEnv | None = None,
        rules: CurriculumRules | None = None,
    ) -> tuple[LoopState, types.Transition]:
        """Several unrolls, reshaped to (sequences, unroll_length, ...), sequences unroll-major."""
        batch_env, rules = batch_env or self.batch_env, rules or self.rules

        def one(carry, _):
            s, k = carry
            k, k_unroll = jax.random.split(k)
            s, data = self._unroll(ts, s, k_unroll, batch_env, rules)
            return (s, k), data

        (state, _), data = jax.lax.scan(one, (state, key), None, length=self.unrolls_per_iteration)
        # (unrolls, T, B, ...) -> (unrolls * B, T, ...)
        data = jax.tree.map(lambda x: jnp.swapaxes(x, 1, 2), data)
        return state, jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), data)

    # ----- learning -----------------------------------------------------------------------
    def _minibatch_step(self, carry, minibatch: types.Transition):
        """One gradient step; a non-finite loss leaves parameters and optimiser untouched."""
        params, opt_state, normalizer, key, skipped = carry
        key, k_loss = jax.random.split(key)
        (loss, metrics), new_params, new_opt = self.update_fn(
            params, normalizer, minibatch, k_loss, optimizer_state=opt_state
        )
        bad = jax.lax.psum(jnp.logical_not(jnp.isfinite(loss)).astype(jnp.int32), AXIS) > 0
        keep = lambda old, new: jax.tree.map(lambda a, b: jnp.where(bad, a, b), old, new)  # noqa: E731
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

    def _curriculum(self, goal: cur.CurriculumState, data: types.Transition) -> cur.CurriculumState:
        """Feed the collection's episode ends to the curriculum in step order, all devices' envs per step.

        The same sequence of updates as one update per env step with outcomes gathered over the
        devices; only the goals of episodes that start during the collection use the range from its
        start (a lag of at most ``unroll_length x unrolls`` steps, see docs/training.md).
        """
        if not self.config.curriculum.enabled:
            return goal
        unrolls, length = self.unrolls_per_iteration, self.config.ppo.unroll_length

        def step_major(x: jax.Array) -> jax.Array:  # (unrolls * B, T) -> (unrolls * T, B)
            x = jnp.swapaxes(x.reshape((unrolls, -1, length)), 1, 2)
            return jax.lax.all_gather(x.reshape((unrolls * length, -1)), AXIS, axis=1, tiled=True)

        extras = data.extras["state_extras"]
        return self.rules.after_collection(
            goal, step_major(extras["goal_reached"]) > 0, step_major(extras["episode_done"]) > 0
        )

    def _learn(
        self, ts: TrainingState, goal: cur.CurriculumState, data: types.Transition, key: jax.Array
    ) -> tuple[TrainingState, cur.CurriculumState, dict]:
        """Observation statistics, curriculum, then ``num_updates_per_batch`` SGD passes over ``data``."""
        obs = data.observation.reshape((-1, data.observation.shape[-1]))
        finite = jnp.all(jnp.isfinite(obs), axis=-1)
        normalizer = ts.normalizer
        if self.config.ppo.normalize_observations:
            normalizer = running_statistics.update(
                normalizer,
                jnp.where(finite[:, None], obs, 0.0),
                weights=finite.astype(jnp.float32),
                pmap_axis_name=AXIS,
            )
        carry = (ts.params, ts.optimizer_state, normalizer, key, jnp.zeros(()))
        (params, opt_state, _, _, skipped), metrics = jax.lax.scan(
            functools.partial(self._sgd_pass, data=data), carry, None, length=self.config.ppo.num_updates_per_batch
        )
        metrics = jax.tree.map(jnp.mean, metrics)
        metrics["skipped_updates"] = skipped
        return TrainingState(params, opt_state, normalizer), self._curriculum(goal, data), metrics

    def _iteration(self, carry, _):
        """Collect, then learn from the collection; new episodes see the updated curriculum."""
        ts, state, key = carry
        key, k_collect, k_sgd = jax.random.split(key, 3)
        state, data = self._collect(ts, state, k_collect)
        ts, goal, metrics = self._learn(ts, state.curricula.goal, data, k_sgd)
        return (ts, state.replace(curricula=state.curricula.replace(goal=goal)), key), metrics

    def _epoch(self, ts: TrainingState, state: LoopState, key: jax.Array):
        """``iterations_per_epoch`` PPO iterations; returns the drained episode totals and losses."""
        (ts, state, _), metrics = jax.lax.scan(
            self._iteration, (ts, state, key), None, length=self.iterations_per_epoch
        )
        state, totals = self._drain(state, self.batch_env, self.rules)
        totals = jax.lax.psum(totals, AXIS)
        metrics = jax.tree.map(jnp.mean, metrics)
        return ts, state, {"totals": totals, "losses": metrics}

    def _drain(self, state: LoopState, batch_env: AutoResetEnv, rules: CurriculumRules) -> tuple[LoopState, dict]:
        """The episode totals and the curricula's per-cell sums since the last drain; both zeroed."""
        envs, totals = batch_env.drain(state.envs)
        curricula, cell_totals = rules.drain(state.curricula)
        return LoopState(envs=envs, curricula=curricula), {**totals, **cell_totals}

    def _collect_epoch(self, ts: TrainingState, state: LoopState, key: jax.Array):
        """``iterations_per_epoch`` collections with the same keys as ``_epoch``, without learning."""

        def one(carry, _):
            state, key = carry
            key, k_collect, _ = jax.random.split(key, 3)
            state, data = self._collect(ts, state, k_collect)
            return (state, key), sum(jnp.sum(x) for x in jax.tree.leaves(data))  # keep every output live

        (state, _), _ = jax.lax.scan(one, (state, key), None, length=self.iterations_per_epoch)
        return ts, state


def replicate(tree: Any, devices: list) -> Any:
    """Copy a pytree onto each device along a new leading axis (for pmapped functions)."""
    return compat.device_put_replicated(tree, devices)


def unreplicate(tree: Any) -> Any:
    """Take the first device's copy of a replicated pytree."""
    return jax.tree.map(lambda x: x[0], tree)

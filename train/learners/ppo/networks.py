"""The PPO networks and the learner's state: Brax's actor and critic MLPs, Adam, observation statistics.

``TrainingState`` is everything the learner owns (parameters, optimiser state, running observation
statistics); ``train.run.saved`` saves and restores it, the learner updates it.
"""

from __future__ import annotations

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before Brax imports it)

# isort: split
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from brax.training import networks as brax_networks
from brax.training import types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks
from flax import linen, struct

from hsa_mjx.deploy.policy_file import ACTIVATIONS as POLICY_ACTIVATIONS
from hsa_mjx.task import privileged
from hsa_mjx.task.types import EnvState

from ...config import TrainConfig
from .update import make_optimizer

# the activations the exported numpy policy can run, as flax functions of the same names
ACTIVATIONS: dict[str, Callable] = {name: getattr(linen, name) for name in POLICY_ACTIVATIONS}


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
        normalize = functools.partial(running_statistics.normalize, max_abs_value=ppo.applied_observation_clip or None)
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
    return privileged.size(config.env.observation, config.env.randomization) if config.ppo.privileged_critic else 0


def network_obs(state: EnvState, with_privileged: bool) -> jax.Array:
    """What the networks read from an env state: the observation, then the privileged inputs when used."""
    if not with_privileged:
        return state.obs
    return jnp.concatenate([state.obs, state.info["privileged_obs"]], axis=-1)


def _strongly_typed(x: Any) -> jax.Array:
    """``x`` as an array of its own dtype, not weakly typed (the normaliser's ``std_eps`` is a Python float)."""
    x = jnp.asarray(x)
    return x.astype(x.dtype)


def init_training_state(
    config: TrainConfig, networks: ppo_networks.PPONetworks, key: jax.Array, observation_size: int
) -> TrainingState:
    """Fresh parameters, optimiser and normaliser state (unreplicated), made by one compiled program
    (not one per operation), every leaf strongly typed as a restored checkpoint's is: a resumed run's
    epoch is then the fresh run's program, which the persistent compilation cache serves."""

    def init(key: jax.Array) -> TrainingState:
        k_policy, k_value = jax.random.split(key)
        params = ppo_losses.PPONetworkParams(
            policy=networks.policy_network.init(k_policy), value=networks.value_network.init(k_value)
        )
        normalizer = running_statistics.init_state(jax.ShapeDtypeStruct((observation_size,), jnp.float32))
        state = TrainingState(
            params=params, optimizer_state=make_optimizer(config.ppo).init(params), normalizer=normalizer
        )
        return jax.tree.map(_strongly_typed, state)

    return jax.jit(init)(key)

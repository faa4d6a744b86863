"""TD3's networks and learner state: a deterministic actor (an MLP, then tanh), two distributional
critics (C51: logits over ``num_atoms`` returns evenly spaced over [v_min, v_max]), their target copies,
AdamW for each, and running observation statistics (Brax's).

The actor's dense layers are ``hidden_0`` ... ``hidden_k`` (the last one gives the action before the
tanh), the layout a policy file holds with ``distribution_type: tanh_normal`` (its output ``tanh``): an
exported TD3 actor runs in the deployment loop as a PPO policy does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from brax.training.acme import running_statistics
from flax import linen, struct

from hsa_mjx.task import privileged

from ...config.td3 import TD3Config


class MLP(linen.Module):
    """Dense layers ``hidden_i`` with ``activation`` between them; the last one linear."""

    sizes: tuple[int, ...]
    activation: str

    @linen.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, size in enumerate(self.sizes):
            x = linen.Dense(size, name=f"hidden_{i}")(x)
            if i < len(self.sizes) - 1:
                x = getattr(linen, self.activation)(x)
        return x


@struct.dataclass
class TD3Networks:
    """The two modules and the sizes they read (static)."""

    actor: MLP = struct.field(pytree_node=False)
    critic: MLP = struct.field(pytree_node=False)
    observation_size: int = struct.field(pytree_node=False)  # the actor's input: the observation alone
    action_size: int = struct.field(pytree_node=False)
    atoms: tuple[float, float, int] = struct.field(pytree_node=False)  # the critics' (v_min, v_max, num_atoms)

    @property
    def support(self) -> jax.Array:
        """The critics' atoms: the returns their logits weigh (num_atoms,)."""
        return jnp.linspace(*self.atoms, dtype=jnp.float32)


@struct.dataclass
class TD3Params:
    """Parameters of the actor and of both critics (stacked on a leading axis of 2), and their targets."""

    actor: Any
    critic: Any
    target_actor: Any
    target_critic: Any


@struct.dataclass
class TD3State:
    """Everything the learner owns and a checkpoint holds (the replay buffer is the loop's, refilled on resume)."""

    params: TD3Params
    actor_optimizer_state: optax.OptState
    critic_optimizer_state: optax.OptState
    normalizer: running_statistics.RunningStatisticsState
    updates: jax.Array  # critic updates so far (int32): the actor updates on every policy_frequency-th


def make_networks(td3: TD3Config, observation_size: int, action_size: int) -> TD3Networks:
    """The actor (observation -> action before tanh) and the critic (network input, action -> logits)."""
    return TD3Networks(
        actor=MLP((*td3.actor_hidden_sizes, action_size), td3.activation),
        critic=MLP((*td3.critic_hidden_sizes, td3.num_atoms), td3.activation),
        observation_size=observation_size,
        action_size=action_size,
        atoms=(float(td3.v_min), float(td3.v_max), int(td3.num_atoms)),
    )


def privileged_size(config: Any) -> int:
    """Privileged inputs the critics read after the observation (0 without ``td3.privileged_critic``)."""
    env = config.env
    return privileged.size(env.observation, env.randomization) if config.td3.privileged_critic else 0


def normalize(normalizer: running_statistics.RunningStatisticsState, x: jax.Array) -> jax.Array:
    """``x`` in standard deviations of the running statistics (their first ``x.shape[-1]`` values)."""
    n = x.shape[-1]
    return (x - normalizer.mean[:n]) / normalizer.std[:n]


def act(networks: TD3Networks, actor: Any, normalizer: Any, obs: jax.Array) -> jax.Array:
    """The deterministic action in [-1, 1] of the network input ``obs`` (the actor reads its observation part)."""
    x = normalize(normalizer, obs[..., : networks.observation_size])
    return jnp.tanh(networks.actor.apply(actor, x))


def critic_logits(networks: TD3Networks, critic: Any, normalizer: Any, obs: jax.Array, action: jax.Array) -> jax.Array:
    """Both critics' logits (2, batch, num_atoms) of (network input, action)."""
    x = jnp.concatenate([normalize(normalizer, obs), action], axis=-1)
    return jax.vmap(lambda p: networks.critic.apply(p, x))(critic)


def make_optimizer(learning_rate: float, td3: TD3Config) -> optax.GradientTransformation:
    """AdamW with the section's weight decay, after a global-norm clip where ``max_grad_norm`` > 0."""
    adam = optax.adamw(learning_rate, weight_decay=td3.weight_decay)
    return optax.chain(optax.clip_by_global_norm(td3.max_grad_norm), adam) if td3.max_grad_norm > 0 else adam


def _strongly_typed(x: Any) -> jax.Array:
    x = jnp.asarray(x)
    return x.astype(x.dtype)


def init_state(td3: TD3Config, networks: TD3Networks, key: jax.Array, input_size: int) -> TD3State:
    """Fresh parameters (targets equal to them), optimisers and statistics, by one compiled program,
    every leaf strongly typed as a restored checkpoint's is."""

    def init(key: jax.Array) -> TD3State:
        k_actor, k_critic = jax.random.split(key)
        actor = networks.actor.init(k_actor, jnp.zeros((1, networks.observation_size)))
        dummy = jnp.zeros((1, input_size + networks.action_size))
        critic = jax.vmap(lambda k: networks.critic.init(k, dummy))(jax.random.split(k_critic))
        params = TD3Params(actor=actor, critic=critic, target_actor=actor, target_critic=critic)
        state = TD3State(
            params=params,
            actor_optimizer_state=make_optimizer(td3.actor_learning_rate, td3).init(actor),
            critic_optimizer_state=make_optimizer(td3.critic_learning_rate, td3).init(critic),
            normalizer=running_statistics.init_state(jax.ShapeDtypeStruct((input_size,), jnp.float32)),
            updates=jnp.zeros((), jnp.int32),
        )
        return jax.tree.map(_strongly_typed, state)

    return jax.jit(init)(key)


def inference(networks: TD3Networks, state: TD3State, deterministic: bool = True, noise_std: float = 0.1) -> Callable:
    """The policy of a learner state as Brax's inference functions are called: (obs, key) -> (action,
    extras); sampled, the action gets Gaussian noise of ``noise_std`` (clipped to [-1, 1])."""

    def policy(obs: jax.Array, key: jax.Array) -> tuple[jax.Array, dict]:
        action = act(networks, state.params.actor, state.normalizer, obs)
        if not deterministic:
            action = jnp.clip(action + noise_std * jax.random.normal(key, action.shape), -1.0, 1.0)
        return action, {}

    return policy

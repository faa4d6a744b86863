"""TD3's learning step on n-step samples: the distributional critics' cross-entropy to the projected
target of the clipped double-Q choice, the actor's ascent of the critics' mean value (every
``policy_frequency``-th step), the targets' Polyak step. A step whose loss is not finite (on any device)
leaves parameters and optimisers as they were and is counted."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from ...config.td3 import TD3Config
from .networks import TD3Networks, TD3State, act, critic_logits, make_optimizer
from .replay import NStep


def project(support: jax.Array, probs: jax.Array, reward: jax.Array, discount: jax.Array) -> jax.Array:
    """C51's projection of the distribution ``probs`` (batch, atoms) on ``support``, moved to
    ``reward + discount x support``, back onto ``support`` (each atom's mass split between its two
    neighbours; moved atoms past the ends are clipped to them)."""
    v_min, v_max, atoms = support[0], support[-1], support.shape[0]
    delta = (v_max - v_min) / (atoms - 1)
    moved = jnp.clip(reward[:, None] + discount[:, None] * support[None, :], v_min, v_max)
    b = (moved - v_min) / delta
    low, high = jnp.floor(b), jnp.ceil(b)
    w_low = (high - b) + (low == high)  # an atom landing exactly on one keeps all of its mass there
    w_high = b - low
    rows = jnp.arange(probs.shape[0])[:, None]
    target = jnp.zeros_like(probs)
    target = target.at[rows, low.astype(jnp.int32)].add(probs * w_low)
    return target.at[rows, high.astype(jnp.int32)].add(probs * w_high)


class TD3Update:
    """The learning step of one config; ``axis`` names the device axis gradients are averaged over."""

    def __init__(self, networks: TD3Networks, td3: TD3Config, axis: str | None):
        self.networks, self.td3, self.axis = networks, td3, axis
        self.actor_optimizer = make_optimizer(td3.actor_learning_rate, td3)
        self.critic_optimizer = make_optimizer(td3.critic_learning_rate, td3)

    def _mean_over_devices(self, x):
        return x if self.axis is None else jax.lax.pmean(x, self.axis)

    def target(self, state: TD3State, batch: NStep, key: jax.Array) -> jax.Array:
        """The critics' target distribution (batch, atoms): the target actor's smoothed action at the
        bootstrap input, the target critic with the lower mean value, projected through the n-step return."""
        net, td3, p = self.networks, self.td3, state.params
        action = act(net, p.target_actor, state.normalizer, batch.next_obs)
        noise = jnp.clip(
            td3.target_noise * jax.random.normal(key, action.shape), -td3.target_noise_clip, td3.target_noise_clip
        )
        action = jnp.clip(action + noise, -1.0, 1.0)
        probs = jax.nn.softmax(critic_logits(net, p.target_critic, state.normalizer, batch.next_obs, action))
        values = probs @ net.support  # (2, batch)
        chosen = jnp.where((values[0] <= values[1])[:, None], probs[0], probs[1])
        return jax.lax.stop_gradient(project(net.support, chosen, batch.reward, batch.discount))

    def critic_loss(self, critic, state: TD3State, batch: NStep, target: jax.Array) -> tuple[jax.Array, dict]:
        """Both critics' cross-entropy to ``target``, summed; and what their values read."""
        logits = critic_logits(self.networks, critic, state.normalizer, batch.obs, batch.action)
        loss = -jnp.sum(target[None] * jax.nn.log_softmax(logits), axis=-1).mean(axis=-1).sum()
        values = jax.nn.softmax(logits) @ self.networks.support
        return loss, {"q_mean": values.mean(), "q_std": values.std(), "q_max": values.max(), "q_min": values.min()}

    def actor_loss(self, actor, state: TD3State, batch: NStep) -> jax.Array:
        """Minus the critics' mean value of the actor's action at the samples' inputs."""
        net = self.networks
        action = act(net, actor, state.normalizer, batch.obs)
        values = jax.nn.softmax(critic_logits(net, state.params.critic, state.normalizer, batch.obs, action))
        return -jnp.mean(values @ net.support)

    def step(self, state: TD3State, batch: NStep, key: jax.Array) -> tuple[TD3State, dict]:
        """One critic update, the actor's when due, the targets' Polyak step."""
        td3, p = self.td3, state.params
        target = self.target(state, batch, key)
        (c_loss, q), c_grads = jax.value_and_grad(self.critic_loss, has_aux=True)(p.critic, state, batch, target)
        c_grads = self._mean_over_devices(c_grads)
        c_updates, c_opt = self.critic_optimizer.update(c_grads, state.critic_optimizer_state, p.critic)
        critic = optax.apply_updates(p.critic, c_updates)
        state_new_critic = state.replace(params=p.replace(critic=critic))
        due = (state.updates % td3.policy_frequency) == 0

        def actor_step(_):
            a_loss, a_grads = jax.value_and_grad(self.actor_loss)(p.actor, state_new_critic, batch)
            a_grads = self._mean_over_devices(a_grads)
            a_updates, a_opt = self.actor_optimizer.update(a_grads, state.actor_optimizer_state, p.actor)
            return optax.apply_updates(p.actor, a_updates), a_opt, a_loss

        def no_actor_step(_):
            return p.actor, state.actor_optimizer_state, jnp.full((), jnp.nan)

        actor, a_opt, a_loss = jax.lax.cond(due, actor_step, no_actor_step, None)
        polyak = lambda old, new: (1.0 - td3.tau) * old + td3.tau * new  # noqa: E731
        params = p.replace(
            actor=actor,
            critic=critic,
            target_actor=jax.tree.map(polyak, p.target_actor, actor),
            target_critic=jax.tree.map(polyak, p.target_critic, critic),
        )
        new = state.replace(params=params, actor_optimizer_state=a_opt, critic_optimizer_state=c_opt)
        new = new.replace(updates=state.updates + 1)
        finite = jnp.isfinite(c_loss) & (jnp.isfinite(a_loss) | ~due)
        bad = self._mean_over_devices((~finite).astype(jnp.float32)) > 0
        kept = jax.tree.map(lambda old, fresh: jnp.where(bad, old, fresh), state, new)
        kept = kept.replace(updates=state.updates + 1)
        metrics = {
            "critic_loss": c_loss,
            "actor_loss": a_loss,
            "critic_grad_norm": jnp.sqrt(sum(jnp.sum(g**2) for g in jax.tree.leaves(c_grads))),
            "target_q_mean": jnp.mean(target @ self.networks.support),
            "skipped_updates": bad.astype(jnp.float32),
            **q,
        }
        return kept, metrics

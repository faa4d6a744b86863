"""PPO's loss and gradient step, with the value targets held still or recomputed, and the diagnostics.

Brax's ``compute_ppo_loss`` recomputes the GAE value targets inside every minibatch from the critic
being trained (``ppo.value_targets: per_minibatch``, the default, reproduced here to the bit). The
regression then chases its own bootstrap: after a fresh start every env is in nearly the same state,
consecutive states are nearly the same, and over the 32 x 4 minibatch steps of one learning step the
values grow geometrically (the flat task at 8,192 envs: value loss 2.1 -> 1.8e6 within the first
learning step, values near 1e5; docs/training.md, "The learning step"). ``per_iteration`` computes the
advantages and value targets once per collection from the critic that saw it, as rsl_rl, CleanRL and
Stable-Baselines3 do.

Also here: the clipped value loss (``ppo.value_clip``), the learning rate, fixed or adapted to the KL
divergence of each minibatch (``ppo.learning_rate_schedule: adaptive_kl``, rsl_rl's rule), and what a
PPO engineer reads first: KL, clip fraction, explained variance, gradient norm, learning rate.
"""

from __future__ import annotations

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before Brax imports it)

# isort: split
from typing import Any

import jax
import jax.numpy as jnp
import optax
from brax.training import types
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks

LR_BOUNDS = (1e-5, 1e-2)  # the adaptive learning rate stays inside these (rsl_rl's)
LR_FACTOR = 1.5  # rsl_rl's step: KL above 2x the target divides the rate by it, below half multiplies


def make_optimizer(ppo: Any) -> optax.GradientTransformation:
    """Adam with global-norm gradient clipping; with ``adaptive_kl`` its rate lives in the optimiser state."""
    if ppo.learning_rate_schedule == "adaptive_kl":
        adam = optax.inject_hyperparams(optax.adam)(learning_rate=ppo.learning_rate)
    else:
        adam = optax.adam(ppo.learning_rate)
    return optax.chain(optax.clip_by_global_norm(ppo.max_grad_norm), adam)


def learning_rate(opt_state: Any, ppo: Any) -> jax.Array:
    """The learning rate the next step uses."""
    if ppo.learning_rate_schedule == "adaptive_kl":
        return optax.tree_utils.tree_get(opt_state, "learning_rate")
    return jnp.asarray(ppo.learning_rate, jnp.float32)


def adapted_learning_rate(rate: jax.Array, kl: jax.Array, desired_kl: float) -> jax.Array:
    """rsl_rl's rule: KL above twice the target divides the rate by 1.5, below half of it multiplies it."""
    rate = jnp.where(kl > 2.0 * desired_kl, rate / LR_FACTOR, rate)
    rate = jnp.where((kl < 0.5 * desired_kl) & (kl > 0.0), rate * LR_FACTOR, rate)
    return jnp.clip(rate, *LR_BOUNDS)


class PPOUpdate:
    """The loss and one gradient step of PPO for the learner's networks and ``ppo`` config.

    Args:
        networks: Brax's PPO networks (policy, value, action distribution).
        ppo: the ``ppo`` config section.
        axis: the device axis gradients and KL are averaged over (None: one device).
    """

    def __init__(self, networks: ppo_networks.PPONetworks, ppo: Any, axis: str | None):
        self.networks, self.ppo, self.axis = networks, ppo, axis
        self.optimizer = make_optimizer(ppo)

    def _mean_over_devices(self, x: Any) -> Any:
        return x if self.axis is None else jax.lax.pmean(x, self.axis)

    def targets(self, params: Any, normalizer: Any, data: types.Transition) -> dict[str, jax.Array]:
        """GAE from the critic ``params``: {"value", "target", "advantage"} of every step, (B, T) like the data."""
        return jax.tree.map(_swap, self._gae(params, normalizer, jax.tree.map(_swap, data)))

    def _gae(self, params: Any, normalizer: Any, tm: types.Transition) -> dict[str, jax.Array]:
        """:meth:`targets` of time-major data, time-major (GAE runs backwards in time)."""
        ppo, value_apply = self.ppo, self.networks.value_network.apply
        values = value_apply(normalizer, params.value, tm.observation)
        bootstrap = value_apply(normalizer, params.value, tm.next_observation[-1])
        truncation = tm.extras["state_extras"]["truncation"]
        termination = (1.0 - tm.discount) * (1.0 - truncation)
        target, advantage = ppo_losses.compute_gae(
            truncation, termination, tm.reward * ppo.reward_scaling, values, bootstrap, ppo.gae_lambda, ppo.discounting
        )
        out = {"value": values, "target": target, "advantage": advantage}
        return jax.tree.map(jax.lax.stop_gradient, out)

    def loss(
        self, params: Any, normalizer: Any, data: types.Transition, key: jax.Array, fixed: dict[str, jax.Array]
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """PPO's clipped surrogate, value and entropy losses of a minibatch; ``fixed``: its rows of :meth:`targets`
        (the value targets and advantages with ``per_iteration``, the rollout values for ``value_clip``).

        Computed time-major and in the order Brax's ``compute_ppo_loss`` computes them, so that
        ``per_minibatch`` reproduces it to the bit (the entropy's samples follow the array layout)."""
        ppo, dist = self.ppo, self.networks.parametric_action_distribution
        tm, fixed = jax.tree.map(_swap, data), jax.tree.map(_swap, fixed)
        logits = self.networks.policy_network.apply(normalizer, params.policy, tm.observation)
        value = self.networks.value_network.apply(normalizer, params.value, tm.observation)
        current = self._gae(params, normalizer, tm) if ppo.value_targets == "per_minibatch" else fixed
        extras = tm.extras["policy_extras"]
        advantage = current["advantage"]
        if ppo.normalize_advantage:
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        ratio = jnp.exp(dist.log_prob(logits, extras["raw_action"]) - extras["log_prob"])
        clipped = jnp.clip(ratio, 1.0 - ppo.clipping_epsilon, 1.0 + ppo.clipping_epsilon)
        policy_loss = -jnp.mean(jnp.minimum(ratio * advantage, clipped * advantage))
        error = (current["target"] - value) * (current["target"] - value)
        if ppo.value_clip > 0:  # the value moves at most value_clip from the rollout's (rsl_rl)
            near = fixed["value"] + jnp.clip(value - fixed["value"], -ppo.value_clip, ppo.value_clip)
            error = jnp.maximum(error, (current["target"] - near) ** 2)
        v_loss = jnp.mean(error) * 0.5 * ppo.vf_loss_coefficient
        entropy_loss = ppo.entropy_cost * -jnp.mean(dist.entropy(logits, key))
        total = policy_loss + v_loss + entropy_loss
        new, old = dist.create_dist(logits), dist.create_dist(extras["distribution_params"])
        return total, {
            "total_loss": total,
            "policy_loss": policy_loss,
            "v_loss": v_loss,
            "entropy_loss": entropy_loss,
            "kl_mean": jnp.mean(new.kl_divergence(old)),
            "clip_fraction": jnp.mean((jnp.abs(ratio - 1.0) > ppo.clipping_epsilon).astype(jnp.float32)),
            "policy_dist_mean_std": jnp.mean(new.scale),
        }

    def step(
        self, params: Any, opt_state: Any, normalizer: Any, minibatch: types.Transition, key: jax.Array
    ) -> tuple[jax.Array, dict[str, jax.Array], Any, Any]:
        """One gradient step on a minibatch (its targets in ``extras["targets"]``): (loss, metrics, params,
        optimiser state). Gradients, and the KL that adapts the rate, are averaged over the devices."""
        fixed = minibatch.extras["targets"]
        grad_fn = jax.value_and_grad(self.loss, has_aux=True)
        (loss, metrics), grads = grad_fn(params, normalizer, minibatch, key, fixed)
        grads = self._mean_over_devices(grads)
        if self.ppo.learning_rate_schedule == "adaptive_kl":
            kl = self._mean_over_devices(metrics["kl_mean"])
            rate = adapted_learning_rate(learning_rate(opt_state, self.ppo), kl, self.ppo.desired_kl)
            opt_state = optax.tree_utils.tree_set(opt_state, learning_rate=rate)
        metrics["grad_norm"] = jnp.sqrt(sum(jnp.sum(jnp.square(g)) for g in jax.tree.leaves(grads)))
        metrics["learning_rate"] = learning_rate(opt_state, self.ppo)
        updates, opt_state = self.optimizer.update(grads, opt_state, params)
        return loss, metrics, optax.apply_updates(params, updates), opt_state


def _swap(x: jax.Array) -> jax.Array:
    """(B, T, ...) <-> (T, B, ...)."""
    return jnp.swapaxes(x, 0, 1)


def with_targets(data: types.Transition, targets: dict[str, jax.Array]) -> types.Transition:
    """The collection with its :meth:`PPOUpdate.targets` in ``extras["targets"]`` (shuffled with it)."""
    return types.Transition(
        observation=data.observation,
        action=data.action,
        reward=data.reward,
        discount=data.discount,
        next_observation=data.next_observation,
        extras={**data.extras, "targets": targets},
    )


def explained_variance(targets: dict[str, jax.Array]) -> jax.Array:
    """1 - Var(target - value) / Var(target) of a collection (1: the critic predicts the returns, <= 0: no
    better than their mean)."""
    target, value = targets["target"], targets["value"]
    return 1.0 - jnp.var(target - value) / jnp.maximum(jnp.var(target), 1e-8)

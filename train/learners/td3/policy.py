"""TD3's learner state as the run, warm starts, evaluation and export see a learner
(``train.learners.registry.Learner``): a fresh state to restore into, the actor to play (its action, or
with exploration noise), the actor as a policy file holds it (``distribution_type: tanh_normal``: dense
layers, then tanh), and the two warm starts."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from hsa_mjx.deploy import policy_file

from ..ppo.policy import file_arrays, restart_count, statistics_from_policy
from .networks import TD3Networks, TD3State, inference, init_state, make_networks, privileged_size

NAME = "td3"
NETWORK_KEYS = ("actor_hidden_sizes", "critic_hidden_sizes", "activation", "num_atoms", "normalize_observations")


def fresh_state(config: Any, observation_size: int, action_size: int) -> tuple[TD3Networks, TD3State]:
    """(networks, a fresh learner state) for ``config``: the structure a checkpoint is restored into."""
    networks = make_networks(config.td3, observation_size, action_size)
    return networks, init_state(config.td3, networks, jax.random.PRNGKey(0), observation_size + privileged_size(config))


def inference_fn(networks: TD3Networks, ts: TD3State, deterministic: bool = True) -> Callable:
    """The actor of a learner state: observations to (actions, extras); sampled, with Gaussian noise of 0.1."""
    return inference(networks, ts, deterministic)


def network_description(config: Any) -> dict[str, Any]:
    """The actor's figures a policy file records beside its arrays."""
    return {"activation": config.td3.activation, "distribution_type": "tanh_normal", "observation_clip": 0.0}


def checkpoint_mismatch(source: Any, config: Any) -> list[str]:
    """Why another run's networks (written with ``source``) cannot start a run of ``config``."""
    if source.run.learner != config.run.learner:
        return [f"run.learner ({source.run.learner!r} vs {config.run.learner!r})"]
    bad = [
        f"td3.{k} ({getattr(source.td3, k)!r} vs {getattr(config.td3, k)!r})"
        for k in NETWORK_KEYS
        if getattr(source.td3, k) != getattr(config.td3, k)
    ]
    if privileged_size(source) != privileged_size(config):
        bad.append(f"privileged critic inputs ({privileged_size(source)} vs {privileged_size(config)})")
    return bad


def policy_mismatch(policy: policy_file.NumpyPolicy, config: Any) -> list[str]:
    """Why a policy file's network cannot start this config's actor."""
    net, td3 = policy.meta["network"], config.td3
    hidden = [int(layer["out"]) for layer in net["layers"][:-1]]
    bad = []
    for key, theirs, ours in (
        ("actor_hidden_sizes", hidden, list(td3.actor_hidden_sizes)),
        ("activation", net["activation"], td3.activation),
    ):
        if theirs != ours:
            bad.append(f"td3.{key} ({theirs!r} vs {ours!r})")
    if net["distribution_type"] != "tanh_normal" or float(net["observation_clip"]) != 0.0:
        bad.append("a policy file whose output is tanh of its last layer, without an observation clip")
    return bad


def from_checkpoint(ts: TD3State, restored: TD3State, count: int | None) -> TD3State:
    """``ts`` with another run's networks (targets too) and observation statistics; fresh optimisers."""
    normalizer = restart_count(restored.normalizer, count) if count else restored.normalizer
    return ts.replace(params=restored.params, normalizer=normalizer)


def from_policy(ts: TD3State, policy: policy_file.NumpyPolicy, count: int) -> TD3State:
    """The policy file's layers in the actor and its target, its normaliser; the critics stay fresh."""
    actor = jax.tree.map(lambda x: x, ts.params.actor)
    for i, (kernel, bias) in enumerate(zip(policy.params["kernels"], policy.params["biases"])):
        layer = actor["params"][f"hidden_{i}"]
        rows = kernel.shape[0]
        weights = jnp.zeros_like(layer["kernel"]).at[:rows].set(kernel)  # inputs the file lacks: zero weights
        actor["params"][f"hidden_{i}"] = {"kernel": weights, "bias": jnp.asarray(bias, layer["bias"].dtype)}
    params = ts.params.replace(actor=actor, target_actor=actor)
    return ts.replace(params=params, normalizer=statistics_from_policy(ts.normalizer, policy, count))


def policy_arrays(config: Any, ts: TD3State, action_size: int) -> dict:
    """The actor's float32 arrays (normaliser of its own inputs, dense layers), as a policy file holds them."""
    tree = ts.params.actor["params"]
    dense = [tree[f"hidden_{i}"] for i in range(len(tree))]
    return file_arrays(dense, ts.normalizer if config.td3.normalize_observations else None)

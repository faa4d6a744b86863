"""PPO's learner state as the run, warm starts, evaluation and export see a learner
(``train.learners.registry.Learner``): a fresh state to restore a checkpoint into, the policy to play,
the deterministic policy as a policy file holds it (``hsa_mjx.deploy.policy_file``), and the two warm
starts (another run's state, a policy file's layers and normaliser). It also knows where each dense
layer of a Brax policy sits in its parameters."""

from __future__ import annotations

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before Brax imports it)

# isort: split
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.training.agents.ppo import networks as ppo_networks

from hsa_mjx.deploy import policy_file

from ...config import TrainConfig
from .networks import TrainingState, init_training_state, make_networks, privileged_size

NAME = "ppo"  # the config section of this learner's keys
NETWORK_KEYS = (  # the section's keys a checkpoint's networks are built from: they must match to resume
    "policy_hidden_sizes",
    "value_hidden_sizes",
    "activation",
    "normalize_observations",
    "distribution_type",
    "noise_std_type",
)


def fresh_state(config: TrainConfig, observation_size: int, action_size: int) -> tuple[Any, TrainingState]:
    """(networks, a fresh learner state) for ``config``: the structure a checkpoint is restored into."""
    extra = privileged_size(config)  # a privileged critic's inputs: in the checkpoint, never in the policy's input
    networks = make_networks(config, observation_size, action_size, extra)
    return networks, init_training_state(config, networks, jax.random.PRNGKey(0), observation_size + extra)


def inference_fn(networks: Any, ts: TrainingState, deterministic: bool = True) -> Callable:
    """The policy of a learner state: observations to (actions, extras), its mean action or sampled."""
    return ppo_networks.make_inference_fn(networks)((ts.normalizer, ts.params.policy), deterministic=deterministic)


def network_description(config: TrainConfig) -> dict[str, Any]:
    """The policy network's figures a policy file records beside its arrays."""
    ppo = config.ppo
    return {
        "activation": ppo.activation,
        "distribution_type": ppo.distribution_type,
        "observation_clip": ppo.applied_observation_clip,
    }


def checkpoint_mismatch(source: TrainConfig, config: TrainConfig) -> list[str]:
    """Why another run's networks (written with ``source``) cannot start a run of ``config``."""
    bad = [
        f"ppo.{k} ({getattr(source.ppo, k)!r} vs {getattr(config.ppo, k)!r})"
        for k in NETWORK_KEYS
        if getattr(source.ppo, k) != getattr(config.ppo, k)
    ]
    if privileged_size(source) != privileged_size(config):
        bad.append(
            f"privileged critic inputs ({privileged_size(source)} vs {privileged_size(config)}: "
            "ppo.privileged_critic, env.observation.height_scan)"
        )
    return bad


def policy_mismatch(policy: policy_file.NumpyPolicy, config: TrainConfig) -> list[str]:
    """Why a policy file's network cannot start this config's policy network."""
    net, ppo = policy.meta["network"], config.ppo
    hidden = [int(layer["out"]) for layer in net["layers"][:-1]]
    bad = []
    for key, theirs, ours in (
        ("policy_hidden_sizes", hidden, list(ppo.policy_hidden_sizes)),
        ("activation", net["activation"], ppo.activation),
        ("distribution_type", net["distribution_type"], ppo.distribution_type),
        ("observation_clip", float(net["observation_clip"]), ppo.applied_observation_clip),
    ):
        if theirs != ours:
            bad.append(f"ppo.{key} ({theirs!r} vs {ours!r})")
    return bad


def from_checkpoint(ts: TrainingState, restored: TrainingState, count: int | None) -> TrainingState:
    """``ts`` with another run's networks and observation statistics (their count restarted at ``count``)."""
    # Adam's initial state does not depend on the parameter values: the fresh one stays valid
    normalizer = restart_count(restored.normalizer, count) if count else restored.normalizer
    return ts.replace(params=restored.params, normalizer=normalizer)


def from_policy(ts: TrainingState, policy: policy_file.NumpyPolicy, count: int) -> TrainingState:
    """The policy file's layers and normaliser in ``ts``; the value network and noise scale stay fresh."""
    ts = with_policy_layers(ts, policy.params["kernels"], policy.params["biases"])
    return ts.replace(normalizer=statistics_from_policy(ts.normalizer, policy, count))


# ----- the policy network's dense layers ----------------------------------------------------
def layer_paths(tree: dict) -> list[tuple[str, ...]]:
    """Where each dense layer of a Brax policy's parameters sits, input first: one MLP for a
    ``tanh_normal`` policy (its last layer outputs mean and scale), or for a ``normal`` one a hidden
    MLP, then the mean layer (its std is a separate parameter)."""
    if "MLP_0" in tree:
        return [("MLP_0", f"hidden_{i}") for i in range(len(tree["MLP_0"]))] + [("Dense_0",)]
    return [(f"hidden_{i}",) for i in range(len(tree))]


def layer_at(tree: dict, path: tuple[str, ...]) -> dict:
    """The layer dict (``kernel``, ``bias``) at ``path``."""
    for part in path:
        tree = tree[part]
    return tree


def policy_arrays(config: TrainConfig, ts: TrainingState, action_size: int) -> dict:
    """The deterministic policy's float32 arrays (normaliser as applied, dense layers) of a training state,
    as a policy file holds them (``hsa_mjx.deploy.policy_file``)."""
    tree = ts.params.policy["params"]
    dense = [dict(layer_at(tree, path)) for path in layer_paths(tree)]
    # a tanh_normal policy's last layer also outputs the noise scale: the mean is its first action_size
    dense[-1] = {
        "kernel": np.asarray(dense[-1]["kernel"])[:, :action_size],
        "bias": np.asarray(dense[-1]["bias"])[:action_size],
    }
    return file_arrays(dense, ts.normalizer if config.ppo.normalize_observations else None)


def file_arrays(dense: list[dict], normalizer: Any | None) -> dict:
    """A policy file's float32 arrays of dense layers (input first) and the statistics that normalise
    their input (None: no normalisation): their first values, the policy's own inputs (a privileged
    critic's follow them in the statistics)."""
    n_obs = np.asarray(dense[0]["kernel"]).shape[0]
    if normalizer is not None:
        mean, std = normalizer.mean[:n_obs], normalizer.std[:n_obs]
    else:
        mean, std = np.zeros(n_obs), np.ones(n_obs)

    def f32(x: Any) -> np.ndarray:
        return np.asarray(x, np.float32)

    return {
        "obs_mean": f32(mean),
        "obs_std": f32(std),
        "kernels": tuple(f32(d["kernel"]) for d in dense),
        "biases": tuple(f32(d["bias"]) for d in dense),
    }


def with_policy_layers(ts: TrainingState, kernels: tuple, biases: tuple) -> TrainingState:
    """``ts`` with a policy file's dense layers in its policy network (the last layer's noise-scale
    outputs of a ``tanh_normal`` policy, which the file does not hold, stay as they are). Inputs the
    file's first layer lacks (a history added after its observation) get zero weights: the policy
    starts as the file's and learns to use them."""
    new = jax.tree.map(lambda x: x, ts.params.policy["params"])  # fresh containers to write into
    for path, kernel, bias in zip(layer_paths(new), kernels, biases):
        layer = layer_at(new, path)
        rows, out = kernel.shape
        weights = jnp.asarray(layer["kernel"])
        weights = weights.at[rows:, :].set(0.0) if rows < weights.shape[0] else weights
        layer["kernel"] = weights.at[:rows, :out].set(kernel)
        layer["bias"] = jnp.asarray(layer["bias"]).at[:out].set(bias)
    return ts.replace(params=ts.params.replace(policy={**ts.params.policy, "params": new}))


# ----- observation statistics (Brax's running statistics) ------------------------------------
def statistics_from_policy(stats: Any, policy: policy_file.NumpyPolicy, count: int) -> Any:
    """Running statistics with the policy file's mean and std, as if from ``count`` samples."""
    mean, std = (jnp.asarray(policy.params[k], jnp.float32) for k in ("obs_mean", "obs_std"))
    size = stats.mean.shape[0]  # a privileged critic's inputs follow the policy's: their statistics stay fresh
    n = mean.shape[0]
    full_mean, full_std = stats.mean.at[:n].set(mean), stats.std.at[:n].set(std)
    new_count = _count_like(stats.count, count)
    variance = jnp.where(jnp.arange(size) < n, full_std**2 * count, stats.summed_variance)
    return stats.replace(count=new_count, mean=full_mean, std=full_std, summed_variance=variance)


def _count_like(old: Any, count: int) -> Any:
    """``count`` in the type of a statistics' sample count (Brax's two-word UInt64, or an array)."""
    if hasattr(old, "hi"):
        return type(old)(hi=jnp.full_like(old.hi, count >> 32), lo=jnp.full_like(old.lo, count & 0xFFFFFFFF))
    return jnp.asarray(count, jnp.asarray(old).dtype)


def restart_count(stats: Any, count: int) -> Any:
    """Observation statistics with the same mean and std as if from ``count`` samples (never more than they had).

    Brax's running statistics weigh a new batch by batch size / total count; a smaller count lets
    a fine-tune's new observations move them quickly. The summed variance scales with the count.
    """
    old = stats.count
    old = float(old.hi) * 2.0**32 + float(old.lo) if hasattr(old, "hi") else float(old)
    if old <= count:
        return stats
    factor = count / old
    new_count = _count_like(stats.count, count)
    return stats.replace(count=new_count, summed_variance=jax.tree.map(lambda v: v * factor, stats.summed_variance))

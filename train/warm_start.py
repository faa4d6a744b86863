"""Starting a run from another one's networks (``run.init_from`` / ``--init-from``).

Two sources, both checked against the config before anything compiles:

- a **run dir or checkpoint dir**: its policy and value networks and observation statistics;
- a **policy directory** (``policies/flat``, or a shipped policy's name): its policy network and
  observation normaliser. The file holds the deterministic policy alone, so the value network and
  the policy's noise scale start fresh, and the normaliser's sample count is
  ``run.init_normalizer_count`` (default ``POLICY_NORMALIZER_COUNT``).

Either way the optimiser, curriculum and step count start fresh.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from hsa_mjx.deploy import policy_file
from hsa_mjx.task import history
from hsa_mjx.task.observation import observation_labels, observation_size

from . import checkpoint, run_state
from .config import TrainConfig
from .networks import TrainingState, privileged_size

POLICY_NORMALIZER_COUNT = 100_000  # samples the shipped statistics count as when a run starts from a policy file


def read_init_from(config: TrainConfig) -> dict | None:
    """What ``run.init_from`` names, checked against this config's networks (before any compile)."""
    if not config.run.init_from:
        return None
    directory = policy_file.find(config.run.init_from)
    if directory is not None:
        return _read_policy(config, directory)
    source = Path(config.run.init_from)
    if not source.exists():
        raise FileNotFoundError(
            f"run.init_from: {source} not found (give a run dir, one of its checkpoint dirs, "
            "a policy dir or a shipped policy's name)"
        )
    src, path, step = run_state.open_run(source)
    bad = [
        f"ppo.{k} ({getattr(src.ppo, k)!r} vs {getattr(config.ppo, k)!r})"
        for k in checkpoint.COMPATIBLE_PPO_KEYS
        if getattr(src.ppo, k) != getattr(config.ppo, k)
    ]
    bad += _observation_mismatch(observation_size(src.env.observation), config)
    if privileged_size(src) != privileged_size(config):
        bad.append(
            f"privileged critic inputs ({privileged_size(src)} vs {privileged_size(config)}: ppo.privileged_critic, "
            "env.observation.height_scan)"
        )
    if bad:
        raise ValueError(f"run.init_from: the networks of {path} do not fit this config: {bad}")
    return {"path": path, "step": step, "source": src, "count": config.run.init_normalizer_count}


def _observation_mismatch(size: int, config: TrainConfig) -> list[str]:
    """A complaint when a source's observation size differs from this config's."""
    own = observation_size(config.env.observation)
    if size == own:
        return []
    return [
        f"observation size ({size} vs {own}: env.observation: heading, servo_targets, clock_period_s, path_direction, "
        "hinge_angles, height_scan)"
    ]


def _policy_observation_mismatch(policy: policy_file.NumpyPolicy, config: TrainConfig) -> list[str]:
    """A complaint unless the policy reads this config's observation, or its first slots with only a
    history after them (``observation.history_steps``: those inputs start silent, see ``with_policy_layers``)."""
    theirs = list(policy.meta["observation"]["labels"])
    ours = list(observation_labels(config.env.observation))
    added = ours[len(theirs) :]
    if ours[: len(theirs)] == theirs and all(history.is_history(label) for label in added):
        return []
    return _observation_mismatch(len(theirs), config) or [
        f"observation slots (the policy's {len(theirs)} are not this config's first ones)"
    ]


def _read_policy(config: TrainConfig, directory: Path) -> dict:
    """A policy directory as a warm start: loaded and checked against the config's policy network."""
    policy = policy_file.load_policy(directory)
    net, ppo = policy.meta["network"], config.ppo
    hidden = [int(layer["out"]) for layer in net["layers"][:-1]]
    bad = _policy_observation_mismatch(policy, config)
    for key, theirs, ours in (
        ("policy_hidden_sizes", hidden, list(ppo.policy_hidden_sizes)),
        ("activation", net["activation"], ppo.activation),
        ("distribution_type", net["distribution_type"], ppo.distribution_type),
        (
            "observation_clip",
            float(net["observation_clip"]),
            ppo.applied_observation_clip,
        ),
    ):
        if theirs != ours:
            bad.append(f"ppo.{key} ({theirs!r} vs {ours!r})")
    if bad:
        raise ValueError(f"run.init_from: the policy in {directory} does not fit this config: {bad}")
    step = int(policy.meta.get("source", {}).get("env_steps") or 0)
    return {
        "policy": policy,
        "path": directory,
        "step": step,
        "count": config.run.init_normalizer_count or POLICY_NORMALIZER_COUNT,
    }


def describe(init: dict) -> str:
    """The line a run prints when it starts from ``init`` (from :func:`read_init_from`)."""
    policy = "policy" in init
    what = (
        "the policy network and observation statistics of the policy file"
        if policy
        else "networks and observation statistics from"
    )
    return (
        f"starting from {what} {init['path']} (trained for {init['step']:,} env steps)"
        + (f", statistics' count restarted at {init['count']:,}" if init["count"] else "")
        + ("; the value network starts fresh" if policy else "")
    )


def warm_start(ts: TrainingState, init: dict) -> TrainingState:
    """``ts`` with the networks and observation statistics ``init`` (from :func:`read_init_from`) names."""
    if "policy" in init:
        return _from_policy(ts, init["policy"], init["count"])
    restored = run_state.restore_training_state(init["path"], ts, init["source"])
    # Adam's initial state does not depend on the parameter values: the fresh one stays valid
    normalizer = restart_count(restored.normalizer, init["count"]) if init.get("count") else restored.normalizer
    return ts.replace(params=restored.params, normalizer=normalizer)


def _from_policy(ts: TrainingState, policy: policy_file.NumpyPolicy, count: int) -> TrainingState:
    """The policy file's layers and normaliser in ``ts``; the value network and noise scale stay fresh."""
    ts = run_state.with_policy_layers(ts, policy.params["kernels"], policy.params["biases"])
    return ts.replace(normalizer=_statistics(ts.normalizer, policy, count))


def _statistics(stats: Any, policy: policy_file.NumpyPolicy, count: int) -> Any:
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

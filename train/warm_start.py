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

from hsa_mjx.curricula import goal as cur
from hsa_mjx.deploy import policy as pol
from hsa_mjx.task.observation import observation_size
from train import checkpoint
from train import config as tcfg
from train.ppo import TrainingState, privileged_size

POLICY_NORMALIZER_COUNT = 100_000  # samples the shipped statistics count as when a run starts from a policy file


def read_init_from(config: tcfg.TrainConfig) -> dict | None:
    """What ``run.init_from`` names, checked against this config's networks (before any compile)."""
    if not config.run.init_from:
        return None
    directory = pol.find(config.run.init_from)
    if directory is not None:
        return _read_policy(config, directory)
    source = Path(config.run.init_from)
    if not source.exists():
        raise FileNotFoundError(
            f"run.init_from: {source} not found (give a run dir, one of its checkpoint dirs, "
            "a policy dir or a shipped policy's name)"
        )
    path = source if (source / checkpoint.META_FILE).is_file() else checkpoint.latest(source)
    meta = checkpoint.read_meta(path)
    src = tcfg.from_dict(meta["config"])
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
    return {**meta, "path": path, "source": src, "count": config.run.init_normalizer_count}


def _observation_mismatch(size: int, config: tcfg.TrainConfig) -> list[str]:
    """A complaint when a source's observation size differs from this config's."""
    own = observation_size(config.env.observation)
    if size == own:
        return []
    return [
        f"observation size ({size} vs {own}: env.observation: heading, servo_targets, clock_period_s, "
        "hinge_angles, height_scan)"
    ]


def _read_policy(config: tcfg.TrainConfig, directory: Path) -> dict:
    """A policy directory as a warm start: loaded and checked against the config's policy network."""
    policy = pol.load_policy(directory)
    net, ppo = policy.meta["network"], config.ppo
    hidden = [int(layer["out"]) for layer in net["layers"][:-1]]
    bad = _observation_mismatch(policy.observation_size, config)
    for key, theirs, ours in (
        ("policy_hidden_sizes", hidden, list(ppo.policy_hidden_sizes)),
        ("activation", net["activation"], ppo.activation),
        ("distribution_type", net["distribution_type"], ppo.distribution_type),
        (
            "observation_clip",
            float(net["observation_clip"]),
            ppo.observation_clip if ppo.normalize_observations else 0.0,
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


def warm_start(ts: TrainingState, init: dict, key: jax.Array) -> TrainingState:
    """``ts`` with the networks and observation statistics ``init`` (from :func:`read_init_from`) names."""
    if "policy" in init:
        return _from_policy(ts, init["policy"], init["count"])
    template = {"training_state": ts, "curriculum": cur.init(init["source"].curriculum), "rng": key}
    restored = jax.tree.map(jnp.asarray, checkpoint.load(init["path"], template)["training_state"])
    # Adam's initial state does not depend on the parameter values: the fresh one stays valid
    normalizer = restart_count(restored.normalizer, init["count"]) if init.get("count") else restored.normalizer
    return ts.replace(params=restored.params, normalizer=normalizer)


def _from_policy(ts: TrainingState, policy: pol.NumpyPolicy, count: int) -> TrainingState:
    """The policy file's layers and normaliser in ``ts``; the value network and noise scale stay fresh."""
    from train.export import layer_at, layer_paths

    new = jax.tree.map(lambda x: x, ts.params.policy["params"])  # fresh containers to write into
    for path, kernel, bias in zip(layer_paths(new), policy.params["kernels"], policy.params["biases"]):
        layer = layer_at(new, path)
        out = kernel.shape[1]  # the last tanh_normal layer also outputs the noise scale: that part stays fresh
        layer["kernel"] = jnp.asarray(layer["kernel"]).at[:, :out].set(kernel)
        layer["bias"] = jnp.asarray(layer["bias"]).at[:out].set(bias)
    params = ts.params.replace(policy={**ts.params.policy, "params": new})
    return ts.replace(params=params, normalizer=_statistics(ts.normalizer, policy, count))


def _statistics(stats: Any, policy: pol.NumpyPolicy, count: int) -> Any:
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

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

from hsa_mjx.deploy import policy_file
from hsa_mjx.task import history
from hsa_mjx.task.observation import observation_labels, observation_size

from ..config import TrainConfig
from ..learners.registry import learner_of
from . import saved

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
    src, path, step = saved.open_run(source)
    bad = learner_of(config).checkpoint_mismatch(src, config)
    bad += _observation_mismatch(observation_size(src.env.observation), config)
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
    history after them (``observation.history_steps``: those inputs start silent, see
    ``train.learners.ppo.policy.with_policy_layers``)."""
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
    bad = _policy_observation_mismatch(policy, config) + learner_of(config).policy_mismatch(policy, config)
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


def warm_start(config: TrainConfig, ts: Any, init: dict) -> Any:
    """``ts`` with the networks and observation statistics ``init`` (from :func:`read_init_from`) names."""
    learner = learner_of(config)
    if "policy" in init:
        return learner.from_policy(ts, init["policy"], init["count"])
    restored = saved.restore_training_state(init["path"], ts, init["source"])
    return learner.from_checkpoint(ts, restored, init.get("count"))

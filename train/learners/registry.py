"""The learners a run can train with, and what the run (checkpoints, warm starts), evaluation and export
use of one: they reach a learner's state only through :class:`Learner`, so a second learner plugs in
here without touching them or PPO."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from hsa_mjx.deploy import policy_file

from ..config import TrainConfig
from .ppo import policy as ppo
from .td3 import policy as td3


class Learner(Protocol):
    """A learner as the rest of the trainer sees it (``train.learners.ppo.policy`` is PPO's)."""

    NAME: str  # its config section
    NETWORK_KEYS: tuple[str, ...]  # the section's keys its networks are built from: they must match to resume

    def fresh_state(self, config: TrainConfig, observation_size: int, action_size: int) -> tuple[Any, Any]: ...

    def inference_fn(self, networks: Any, ts: Any, deterministic: bool = True) -> Callable: ...

    def policy_arrays(self, config: TrainConfig, ts: Any, action_size: int) -> dict: ...

    def network_description(self, config: TrainConfig) -> dict[str, Any]: ...

    def checkpoint_mismatch(self, source: TrainConfig, config: TrainConfig) -> list[str]: ...

    def policy_mismatch(self, policy: policy_file.NumpyPolicy, config: TrainConfig) -> list[str]: ...

    def from_checkpoint(self, ts: Any, restored: Any, count: int | None) -> Any: ...

    def from_policy(self, ts: Any, policy: policy_file.NumpyPolicy, count: int) -> Any: ...


LEARNERS: dict[str, Learner] = {ppo.NAME: ppo, td3.NAME: td3}


def learner_of(config: TrainConfig) -> Learner:
    """The learner ``config`` trains with (``run.learner``)."""
    return LEARNERS[config.run.learner]

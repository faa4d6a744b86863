"""What every collection strategy shares: the learner and its devices, checked once; the learner state
kept one copy per device (``pmap`` layout); and how many envs each process and each device steps (the
one place that divides ``run.num_envs``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax

from ..config import TrainConfig
from ..learners.ppo.learner import AXIS, PPOLearner
from ..learners.td3.learner import TD3Learner
from .replicas import first_copy, replicate


def envs_per_process(config: TrainConfig) -> int:
    """The envs this process steps: its share of ``run.num_envs``."""
    return config.run.num_envs // jax.process_count()


def envs_per_device(config: TrainConfig, devices: Sequence[jax.Device]) -> int:
    """The envs each of this process's ``devices`` steps (every process has as many)."""
    return envs_per_process(config) // len(devices)


class DeviceStrategy:
    """A collection strategy's learner and devices: the learner's device axis is the one the strategy
    needs (``axis``) and its env is built for the batch each device steps (Warp's shared contact buffer)."""

    name = ""
    axis: str | None = AXIS  # the learner's device axis this strategy needs (None: no collective)

    def __init__(self, learner: PPOLearner | TD3Learner, devices: Sequence[jax.Device]):
        if learner.axis != self.axis:
            needs = "without a device axis (axis=None)" if self.axis is None else f"with the device axis {self.axis!r}"
            raise ValueError(f"run.collection {self.name} needs a learner {needs}")
        per_device = envs_per_device(learner.config, devices)
        if learner.env.num_envs != per_device:
            raise ValueError(
                f"the env is built for batches of {learner.env.num_envs}, but each of the {len(devices)} devices "
                f"steps {per_device} envs (run.num_envs {learner.config.run.num_envs}): build it with "
                f"HSAEnv(config.env, num_envs={per_device}) (train.devices.strategies.build does)"
            )
        self.learner, self.devices = learner, list(devices)

    def compile_ahead(self, ts: Any, state: Any, keys: jax.Array, during: Callable[[], Any] | None = None) -> bool:
        """Compile the epoch for these arguments before the first one runs, calling ``during`` on a thread
        meanwhile: True when it did. This strategy compiles at its first epoch (False; ``during`` not
        called)."""
        return False


class Replicated(DeviceStrategy):
    """A strategy that keeps one copy of the learner state per device, as ``pmap`` lays it out."""

    def place(self, ts: Any) -> Any:
        """One copy of the learner state per device."""
        return replicate(ts, self.devices)

    @staticmethod
    def first(ts: Any) -> Any:
        """The first device's copy of the learner state (all are equal)."""
        return first_copy(ts)

"""How the devices share a training epoch: the collection strategies of ``run.collection``.

One learner (``train.learners.ppo.learner.PPOLearner`` or ``train.learners.td3.learner.TD3Learner``: reset,
epoch, drain as pure functions) and one of these strategies, which place its state and call its functions:

- ``one_device``: the epoch jitted for the one device, no collective at all;
- ``pmap``: the epoch ``pmap``-ed over this process's devices (and every process's, with several
  hosts): gradients, observation statistics and curriculum outcomes are reduced over all of them;
- ``thread_per_device`` (``train.devices.thread_per_device``): each GPU its own env copy and jitted
  collection, called from one host thread per GPU, and the learning step ``pmap``-ed;
- ``auto`` (the default): ``one_device`` for one device, ``thread_per_device`` for several local GPUs,
  ``pmap`` otherwise (several CPU devices, or several hosts of one GPU each).

Every strategy takes and returns the same things: the learner state as :meth:`place` lays it out,
epoch outputs with a leading device axis (totals summed over devices, losses per device), host
copies of the curricula. Why several: docs/scaling.md.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import jax
import jax.numpy as jnp

from hsa_mjx.curricula import goal_curriculum
from hsa_mjx.curricula.state import EnvLevels, host_levels
from hsa_mjx.task.env import HSAEnv

from ..config import TrainConfig
from ..learners.ppo.learner import AXIS, LoopState, PPOLearner
from ..learners.ppo.networks import TrainingState
from ..learners.td3.learner import TD3Learner
from . import compat
from .base import DeviceStrategy, Replicated, envs_per_device
from .replicas import PmapWithoutEmpty, first_copy
from .thread_per_device import ThreadPerDevice


class OneDevice(DeviceStrategy):
    """The epoch jitted for one device; the learner runs without a device axis."""

    name = "one_device"
    axis = None

    def __init__(self, learner: PPOLearner | TD3Learner, devices: Sequence[jax.Device]):
        if len(devices) != 1 or jax.process_count() != 1:
            raise ValueError(f"run.collection one_device needs one device, got {len(devices) * jax.process_count()}")
        super().__init__(learner, devices)
        donate = (0, 1) if devices[0].platform != "cpu" else ()  # the CPU client cannot reuse donated buffers
        self._reset = jax.jit(learner.reset)
        self._epoch = jax.jit(self._epoch_with_device_axis, donate_argnums=donate)
        self._collect_epoch = jax.jit(learner.collect_epoch)

    def _epoch_with_device_axis(self, ts: TrainingState, state: LoopState, key: jax.Array):
        """The learner's epoch, its outputs given the leading device axis every strategy returns."""
        ts, state, out = self.learner.epoch(ts, state, key)
        return ts, state, jax.tree.map(lambda x: x[None], out)

    def place(self, ts: TrainingState) -> TrainingState:
        """The learner state on the device."""
        return jax.device_put(ts, self.devices[0])

    @staticmethod
    def first(ts: TrainingState) -> TrainingState:
        """The learner state (the one copy)."""
        return ts

    def reset(
        self,
        env_keys: jax.Array,
        goal: goal_curriculum.GoalCurriculumState,
        levels: EnvLevels | None = None,
    ) -> LoopState:
        """Fresh envs (``env_keys``: (1, envs, 2)) starting from ``goal`` and, when given, every env's
        levels ((envs,) arrays; resume)."""
        device = self.devices[0]
        return self._reset(*jax.device_put((env_keys[0], goal, levels), device))

    def epoch(self, ts: TrainingState, state: LoopState, keys: jax.Array):
        """``iterations_per_epoch`` learner iterations (``keys``: (1, 2)); returns (ts, state, outputs)."""
        return self._epoch(ts, state, keys[0])

    def compile_ahead(self, ts: TrainingState, state: LoopState, keys: jax.Array, during=None) -> bool:
        """Compile the epoch for these arguments now (``jit(...).lower(...).compile()``: the first epoch then
        only runs), calling ``during`` on a thread meanwhile and waiting for it: work that overlaps XLA's
        compile but must not overlap a running program (MuJoCo Warp's kernels built by a warm-up step)."""
        worker = threading.Thread(target=during, name="compile-ahead", daemon=True) if during else None
        if worker is not None:
            worker.start()
        try:
            self._epoch = self._epoch.lower(ts, state, keys[0]).compile()
        finally:
            if worker is not None:
                worker.join()
        return True

    def collect_epoch(self, ts: TrainingState, state: LoopState, keys: jax.Array):
        """The epoch's collections alone, no learning (for timing the update's share)."""
        return self._collect_epoch(ts, state, keys[0])

    @staticmethod
    def env_levels(state: LoopState) -> dict:
        """Every env's terrain type and level and randomisation level as host arrays (envs,)."""
        return host_levels([state.curricula])

    @staticmethod
    def goal_curriculum(state: LoopState) -> goal_curriculum.GoalCurriculumState:
        """The goal curriculum's state."""
        return state.curricula.goal


class Pmap(Replicated):
    """The epoch ``pmap``-ed over the devices; the learner reduces over its device axis."""

    name = "pmap"

    def __init__(self, learner: PPOLearner | TD3Learner, devices: Sequence[jax.Device]):
        super().__init__(learner, devices)
        self._reset = PmapWithoutEmpty(learner.reset, axis_name=AXIS)
        self._epoch = PmapWithoutEmpty(learner.epoch, axis_name=AXIS, donate_argnums=(0, 1))
        self._collect_epoch = PmapWithoutEmpty(learner.collect_epoch, axis_name=AXIS)

    def reset(
        self,
        env_keys: jax.Array,
        goal: goal_curriculum.GoalCurriculumState,
        levels: EnvLevels | None = None,
    ) -> LoopState:
        """Fresh envs (``env_keys``: (devices, envs per device, 2)) starting from ``goal`` (one copy) and,
        when given, the levels of every env ((envs,) arrays in device order; resume)."""
        if levels is not None:
            levels = jax.tree.map(lambda x: jnp.reshape(x, env_keys.shape[:2]), levels)
        return self._reset(jax.device_put(env_keys), compat.device_put_replicated(goal, self.devices), levels)

    def epoch(self, ts: TrainingState, state: LoopState, keys: jax.Array):
        """``iterations_per_epoch`` learner iterations on every device (one key each); returns (ts, state, outputs)."""
        return self._epoch(ts, state, keys)

    def collect_epoch(self, ts: TrainingState, state: LoopState, keys: jax.Array):
        """The epoch's collections alone, no learning (for timing the update's share)."""
        return self._collect_epoch(ts, state, keys)

    @staticmethod
    def env_levels(state: LoopState) -> dict:
        """This process's envs' terrain types and levels and randomisation levels as host arrays (envs,),
        in device order."""
        return host_levels([jax.device_get(state.curricula)])

    @staticmethod
    def goal_curriculum(state: LoopState) -> goal_curriculum.GoalCurriculumState:
        """The goal curriculum's state (the first device's copy; all are equal)."""
        return first_copy(state.curricula.goal)


def resolve_collection(config: TrainConfig, devices: Sequence[jax.Device]) -> str:
    """The strategy ``run.collection`` names over ``devices`` (this process's), ``auto`` resolved."""
    kind = config.run.collection
    if kind != "auto":
        return kind
    if len(devices) * jax.process_count() == 1:
        return "one_device"
    if len(devices) > 1 and devices[0].platform == "gpu" and config.run.learner == "ppo":
        return "thread_per_device"
    return "pmap"


Strategy = OneDevice | Pmap | ThreadPerDevice
STRATEGIES = {"one_device": OneDevice, "pmap": Pmap, "thread_per_device": ThreadPerDevice}


def build(config: TrainConfig, devices: Sequence[jax.Device]) -> Strategy:
    """The learner and the strategy ``run.collection`` asks for over ``devices`` (this process's share),
    the env built for the batch each device steps (``run.num_envs`` over every process's devices): the
    one place that sizes it (Warp's shared contact buffer)."""
    kind = resolve_collection(config, devices)
    env = HSAEnv(config.env, num_envs=envs_per_device(config, devices), privileged=config.privileged_critic)
    learners = {"ppo": PPOLearner, "td3": TD3Learner}
    learner = learners[config.run.learner](config, env, axis=None if kind == "one_device" else AXIS)
    return STRATEGIES[kind](learner, devices)

"""Multi-GPU PPO without ``pmap`` over the physics: one compiled env collection per GPU, one host thread each.

Why: on the H200s (jaxlib 0.11.2) every ``pmap`` of MJX's Newton solver over two or more GPUs
crashes XLA's GPU compiler, while the same collection compiles for one GPU and the learning step
(networks, no MJX) compiles under ``pmap`` (docs/scaling.md). So:

- each GPU gets its own env copy (model and data on that GPU) and its own jitted collection
  (``PPOLearner._collect``); JAX's persistent compilation cache ignores which GPU a program is
  for, so the copies after the first load from it;
- one host thread per GPU calls it: called in turn from one thread (with keys made on GPU 0) the
  GPUs ran one after another on the H200s, likely because MJX's solver ``while_loop`` holds the
  calling thread until the loop ends (docs/scaling.md);
- the learning step (observation statistics, curriculum over every GPU's outcomes in step order,
  SGD with gradients averaged over the GPUs) is ``PPOLearner._learn`` under ``pmap``;
- data moves between the two as the per-GPU pieces of one array (no copy, no host round-trip).

Same random streams and update order as the ``pmap`` epoch: both give the same training run up to
float rounding, as the two are compiled as different programs (tests/test_multi_device.py compares
them on fake CPU devices).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import numpy as np
from flax import struct
from jax.sharding import Mesh, NamedSharding, PartitionSpec, SingleDeviceSharding

from hsa_mjx.batch.auto_reset import AutoResetEnv
from hsa_mjx.curricula import goal as cur
from hsa_mjx.curricula import terrain as tcur
from hsa_mjx.curricula.state import CurriculumRules
from hsa_mjx.task.env import HSAEnv
from train.config import TrainConfig
from train.ppo import AXIS, LoopState, PPOLearner, TrainingState


@struct.dataclass
class DeviceStates:
    """Every GPU's loop state (its env batch and curricula, on its GPU) and the goal curriculum that
    learning updates (one copy per GPU, ``pmap`` layout; copied into each GPU's curricula to collect)."""

    pieces: tuple[LoopState, ...]
    goal: cur.CurriculumState


def split(tree: Any, devices: Sequence[jax.Device]) -> list[Any]:
    """The per-device pieces (leading axis 1) of arrays laid out one slice per device, in ``devices`` order."""
    leaves, treedef = jax.tree.flatten(tree)
    pieces = []
    for leaf in leaves:
        by_device = {shard.device: shard.data for shard in leaf.addressable_shards}
        pieces.append([_single(by_device[d], d) for d in devices])
    return [treedef.unflatten([p[i] for p in pieces]) for i in range(len(devices))]


def _single(x: jax.Array, device: jax.Device) -> jax.Array:
    """``x`` as a plain one-device array (the piece of a one-device mesh keeps the mesh's sharding, and
    a jitted function would compile again for it)."""
    return x if isinstance(x.sharding, SingleDeviceSharding) else jax.device_put(x, SingleDeviceSharding(device))


def stack(trees: Sequence[Any], devices: Sequence[jax.Device]) -> Any:
    """One array per leaf from per-device pieces (leading axis 1, piece i on device i), without copying."""
    sharding = NamedSharding(Mesh(np.array(devices), (AXIS,)), PartitionSpec(AXIS))

    def assemble(*pieces: jax.Array) -> jax.Array:
        return jax.make_array_from_single_device_arrays((len(pieces),) + pieces[0].shape[1:], sharding, list(pieces))

    return jax.tree.map(assemble, *trees)


def _lead(tree: Any) -> Any:
    """Add a leading axis of 1 (inside jit)."""
    return jax.tree.map(lambda x: x[None], tree)


def _unlead(tree: Any) -> Any:
    """Drop the leading axis of 1 (inside jit)."""
    return jax.tree.map(lambda x: x[0], tree)


def _drain_piece(
    state: LoopState, learner: PPOLearner, batch_env: AutoResetEnv, rules: CurriculumRules
) -> tuple[LoopState, dict]:
    """One GPU's drained state and its totals with a leading device axis of 1."""
    state, totals = learner._drain(state, batch_env, rules)
    return state, _lead(totals)


class PerDeviceLearner(PPOLearner):
    """:class:`PPOLearner` whose ``reset``/``epoch`` run the env collection per GPU (see module doc).

    Args:
        config: the training config.
        env: the single-env :class:`HSAEnv` (networks and sizes; each GPU builds its own copy).
        devices: this process's devices to use.
    """

    def __init__(self, config: TrainConfig, env: HSAEnv, devices: Sequence[jax.Device]):
        super().__init__(config, env, len(devices) * jax.process_count())
        self.devices = list(devices)
        self.batch_envs, self.piece_rules = [], []
        for device in self.devices:
            with jax.default_device(device):
                piece = HSAEnv(config.env, num_envs=self.envs_per_device, privileged=config.ppo.privileged_critic)
                self.batch_envs.append(AutoResetEnv(piece))
                self.piece_rules.append(CurriculumRules(piece, config.curriculum, config.terrain_curriculum))
        donate = (2,) if self.devices[0].platform != "cpu" else ()  # CPU buffers cannot be donated
        self.collect_fns = [
            jax.jit(functools.partial(self._collect_piece, batch_env=b, rules=r), donate_argnums=donate)
            for b, r in zip(self.batch_envs, self.piece_rules)
        ]
        self.reset_fns = [
            jax.jit(functools.partial(self._reset, batch_env=b, rules=r))
            for b, r in zip(self.batch_envs, self.piece_rules)
        ]
        self.drain_fns = [
            jax.jit(functools.partial(_drain_piece, learner=self, batch_env=b, rules=r))
            for b, r in zip(self.batch_envs, self.piece_rules)
        ]
        self.learn_fn = jax.pmap(self._learn, axis_name=AXIS)
        self.sum_fn = jax.pmap(lambda t: jax.lax.psum(t, AXIS), axis_name=AXIS)
        self.pool = ThreadPoolExecutor(len(self.devices), thread_name_prefix="hsa-mjx-device")

    def _on_each(self, fn: Callable, *per_device: Sequence) -> list:
        """``fn(i, *args_i)`` for every device at once, one thread each; the results in device order."""
        futures = [self.pool.submit(fn, i, *(args[i] for args in per_device)) for i in range(len(self.devices))]
        return [f.result() for f in futures]

    def _device_keys(self, keys: jax.Array) -> list[jax.Array]:
        """One key per device (leading axis 1), each made on its own device (no wait on another GPU)."""
        return [jax.device_put(np.asarray(k)[None], d) for k, d in zip(np.asarray(keys), self.devices)]

    def _collect_piece(
        self,
        ts: TrainingState,
        goal: cur.CurriculumState,
        state: LoopState,
        key: jax.Array,
        batch_env: AutoResetEnv,
        rules: CurriculumRules,
    ):
        """One GPU's collection (arguments and outputs with a leading device axis of 1, ``state`` without)."""
        ts, goal, key = _unlead((ts, goal, key))
        key, k_collect, k_sgd = jax.random.split(key, 3)
        state = state.replace(curricula=state.curricula.replace(goal=goal))
        state, data = self._collect(ts, state, k_collect, batch_env, rules)
        return state, _lead((data, key, k_sgd))

    def reset(
        self, env_keys: jax.Array, curriculum: cur.CurriculumState, terrain: tcur.TerrainLevels | None = None
    ) -> DeviceStates:
        """Fresh envs (``env_keys``: (devices, envs per device, 2)) starting from ``curriculum`` (unreplicated)
        and, when given, the terrain levels of every env ((envs,) arrays in device order; resume)."""
        keys, host = np.asarray(env_keys), jax.device_get(curriculum)
        levels = (
            [None] * len(self.devices)
            if terrain is None
            else [
                jax.tree.map(lambda x, i=i: np.asarray(x).reshape(keys.shape[:2])[i], terrain)
                for i in range(len(self.devices))
            ]
        )
        envs = self._on_each(
            lambda i, k, t: self.reset_fns[i](*jax.device_put((k, host, t), self.devices[i])), keys, levels
        )
        pieces = [jax.device_put(jax.tree.map(lambda x: np.asarray(x)[None], host), d) for d in self.devices]
        return DeviceStates(pieces=tuple(envs), goal=stack(pieces, self.devices))

    def epoch(self, ts: TrainingState, states: DeviceStates, keys: jax.Array):
        """``iterations_per_epoch`` PPO iterations; returns (ts, states, drained totals and mean losses)."""
        keys = self._device_keys(keys)
        envs, goal, losses = list(states.pieces), states.goal, []
        for _ in range(self.iterations_per_epoch):
            outs = self._on_each(
                lambda i, *a: self.collect_fns[i](*a), split(ts, self.devices), split(goal, self.devices), envs, keys
            )
            envs, keys = [o[0] for o in outs], [o[1][1] for o in outs]
            data, k_sgd = stack([o[1][0] for o in outs], self.devices), stack([o[1][2] for o in outs], self.devices)
            ts, goal, metrics = self.learn_fn(ts, goal, data, k_sgd)
            losses.append(metrics)
        drained = self._on_each(lambda i, s: self.drain_fns[i](s), envs)
        totals = self.sum_fn(stack([d[1] for d in drained], self.devices))
        losses = jax.tree.map(lambda *xs: np.mean(np.stack([np.asarray(x) for x in xs]), axis=0), *losses)
        return ts, DeviceStates(pieces=tuple(d[0] for d in drained), goal=goal), {"totals": totals, "losses": losses}

    def terrain_levels(self, states: DeviceStates) -> dict:
        """This process's envs' terrain type rows and levels as host arrays (envs,), in device order."""
        return tcur.to_host([jax.device_get(s.curricula.terrain) for s in states.pieces])

    @staticmethod
    def goal_curriculum(states: DeviceStates) -> cur.CurriculumState:
        """The goal curriculum's state (the first device's copy; all are equal)."""
        return jax.tree.map(lambda x: x[0], states.goal)

    def collect_epoch(self, ts: TrainingState, states: DeviceStates, keys: jax.Array):
        """The epoch's collections alone (no learning): for timing the update's share (benchmarks.scaling)."""
        keys = self._device_keys(keys)
        envs, cs = list(states.pieces), split(states.goal, self.devices)
        for _ in range(self.iterations_per_epoch):
            outs = self._on_each(lambda i, *a: self.collect_fns[i](*a), split(ts, self.devices), cs, envs, keys)
            envs, keys = [o[0] for o in outs], [o[1][1] for o in outs]
        jax.block_until_ready(envs)
        return ts, DeviceStates(pieces=tuple(envs), goal=states.goal)


def use_per_device(config: TrainConfig, devices: Sequence[jax.Device]) -> bool:
    """Whether ``run.multi_device`` (``auto``: several local GPUs) picks :class:`PerDeviceLearner`."""
    mode = config.run.multi_device
    if mode == "auto":
        return len(devices) > 1 and devices[0].platform == "gpu"
    return mode == "per_device"


def make_learner(config: TrainConfig, devices: Sequence[jax.Device]) -> PPOLearner:
    """The learner ``run.multi_device`` asks for over ``devices`` (this process's share), with its env
    built for the batch each device steps (``run.num_envs`` over every process's devices): the one
    place that sizes it (Warp's shared contact buffer)."""
    count = len(devices) * jax.process_count()
    env = HSAEnv(config.env, num_envs=config.run.num_envs // count, privileged=config.ppo.privileged_critic)
    if use_per_device(config, devices):
        return PerDeviceLearner(config, env, devices)
    return PPOLearner(config, env, count)

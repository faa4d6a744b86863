"""The ``thread_per_device`` collection strategy: one compiled env collection per GPU, one host thread each.

- each GPU gets its own env copy (model and data on that GPU) and its own jitted collection
  (:meth:`PPOLearner.collect`); JAX's persistent compilation cache ignores which GPU a program is
  for, so where one is set (``JAX_COMPILATION_CACHE_DIR``) each program's first call runs on the first
  GPU alone and the others load what it compiled (at once, they would each compile it);
- one host thread per GPU calls it, so that the GPUs collect at the same time (a solver's
  ``while_loop`` can hold its calling thread until the loop ends);
- the learning step (observation statistics, goal curriculum over every GPU's outcomes in step order,
  SGD with gradients averaged over the GPUs) is :meth:`PPOLearner.learn` under ``pmap``;
- data moves between the two as the per-GPU pieces of one array (no copy, no host round-trip).

Same random streams and update order as the ``pmap`` strategy: both give the same training run up
to float rounding, as the two are compiled as different programs (tests/test_multi_device.py
compares them on fake CPU devices). Why MJX's physics is not ``pmap``-ed here: docs/scaling.md.
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
from hsa_mjx.curricula import goal_curriculum
from hsa_mjx.curricula.state import EnvLevels, host_levels
from hsa_mjx.task.env import HSAEnv

from ..learners.ppo.learner import AXIS, LoopState, PPOLearner
from ..learners.ppo.networks import TrainingState
from .base import Replicated
from .replicas import PmapWithoutEmpty, first_copy


@struct.dataclass
class DeviceStates:
    """Every GPU's loop state (its env batch and curricula, on its GPU) and the goal curriculum that
    learning updates (one copy per GPU, ``pmap`` layout; copied into each GPU's curricula to collect)."""

    pieces: tuple[LoopState, ...]
    goal: goal_curriculum.GoalCurriculumState


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


class ThreadPerDevice(Replicated):
    """One env copy and one jitted collection per GPU, called from one thread each; learning ``pmap``-ed.

    Args:
        learner: the learner (with the device axis); each GPU builds its own copy of its env.
        devices: this process's devices to use.
    """

    name = "thread_per_device"

    def __init__(self, learner: PPOLearner, devices: Sequence[jax.Device]):
        super().__init__(learner, devices)
        config = learner.config
        self.batch_envs = []
        for device in self.devices:
            with jax.default_device(device):
                env = HSAEnv(config.env, num_envs=learner.env.num_envs, privileged=config.privileged_critic)
                self.batch_envs.append(AutoResetEnv(env, config.run.regenerate_terrain_every))
        donate = (2,) if self.devices[0].platform != "cpu" else ()  # the CPU client cannot reuse donated buffers
        self._collect = [
            jax.jit(functools.partial(self._collect_piece, batch_env=b), donate_argnums=donate) for b in self.batch_envs
        ]
        self._reset = [jax.jit(functools.partial(learner.reset, batch_env=b)) for b in self.batch_envs]
        self._drain = [jax.jit(functools.partial(self._drain_piece, batch_env=b)) for b in self.batch_envs]
        self._learn = PmapWithoutEmpty(learner.learn, axis_name=AXIS)
        self._sum = PmapWithoutEmpty(lambda t: jax.lax.psum(t, AXIS), axis_name=AXIS)
        self.pool = ThreadPoolExecutor(len(self.devices), thread_name_prefix="hsa-mjx-device")
        self._called: set[str] = set()  # the per-device programs called once already (compiled)

    def on_each(self, fn: Callable, *per_device: Sequence) -> list:
        """``fn(i, *args_i)`` for every device at once, one thread each; the results in device order."""
        futures = [self.pool.submit(fn, i, *(args[i] for args in per_device)) for i in range(len(self.devices))]
        return [f.result() for f in futures]

    def _on_each_compiled_once(self, program: str, fn: Callable, *per_device: Sequence) -> list:
        """``on_each``, except that with a persistent compilation cache the first call of ``program`` runs
        on the first device before the others, which then load its compiled program from the cache."""
        if program in self._called or not jax.config.jax_compilation_cache_dir or len(self.devices) == 1:
            return self.on_each(fn, *per_device)
        self._called.add(program)
        first = fn(0, *(args[0] for args in per_device))
        rest = [self.pool.submit(fn, i, *(args[i] for args in per_device)) for i in range(1, len(self.devices))]
        return [first, *(f.result() for f in rest)]

    def _device_keys(self, keys: jax.Array) -> list[jax.Array]:
        """One key per device (leading axis 1), each made on its own device (no wait on another GPU)."""
        return [jax.device_put(np.asarray(k)[None], d) for k, d in zip(np.asarray(keys), self.devices)]

    def _collect_piece(
        self,
        ts: TrainingState,
        goal: goal_curriculum.GoalCurriculumState,
        state: LoopState,
        key: jax.Array,
        batch_env: AutoResetEnv,
    ):
        """One GPU's collection (arguments and outputs with a leading device axis of 1, ``state`` without)."""
        ts, goal, key = first_copy((ts, goal, key))
        key, k_collect, k_sgd = jax.random.split(key, 3)
        state = state.replace(curricula=state.curricula.replace(goal=goal))
        state, data = self.learner.collect(ts, state, k_collect, batch_env)
        return state, _lead((data, key, k_sgd))

    def _drain_piece(self, state: LoopState, batch_env: AutoResetEnv) -> tuple[LoopState, dict]:
        """One GPU's drained state and its totals with a leading device axis of 1."""
        state, totals = self.learner.drain(state, batch_env)
        return state, _lead(totals)

    def reset(
        self,
        env_keys: jax.Array,
        goal: goal_curriculum.GoalCurriculumState,
        levels: EnvLevels | None = None,
    ) -> DeviceStates:
        """Fresh envs (``env_keys``: (devices, envs per device, 2)) starting from ``goal`` (one copy) and,
        when given, the levels of every env ((envs,) arrays in device order; resume)."""
        keys, host = np.asarray(env_keys), jax.device_get(goal)
        pieces = [None] * len(self.devices)
        if levels is not None:
            pieces = [
                jax.tree.map(lambda x, i=i: np.asarray(x).reshape(keys.shape[:2])[i], levels)
                for i in range(len(self.devices))
            ]
        envs = self._on_each_compiled_once(
            "reset", lambda i, k, t: self._reset[i](*jax.device_put((k, host, t), self.devices[i])), keys, pieces
        )
        goals = [jax.device_put(jax.tree.map(lambda x: np.asarray(x)[None], host), d) for d in self.devices]
        return DeviceStates(pieces=tuple(envs), goal=stack(goals, self.devices))

    def _collect_all(self, ts: TrainingState, goal: Any, envs: list, keys: list) -> tuple[list, list, list]:
        """Every GPU's collection at once: (env states, next keys, (data, SGD key) per GPU)."""
        outs = self._on_each_compiled_once(
            "collect",
            lambda i, *a: self._collect[i](*a),
            split(ts, self.devices),
            split(goal, self.devices),
            envs,
            keys,
        )
        return [o[0] for o in outs], [o[1][1] for o in outs], [(o[1][0], o[1][2]) for o in outs]

    def epoch(self, ts: TrainingState, states: DeviceStates, keys: jax.Array):
        """``iterations_per_epoch`` PPO iterations; returns (ts, states, drained totals and mean losses)."""
        keys = self._device_keys(keys)
        envs, goal, losses = list(states.pieces), states.goal, []
        for _ in range(self.learner.iterations_per_epoch):
            envs, keys, collected = self._collect_all(ts, goal, envs, keys)
            data = stack([c[0] for c in collected], self.devices)
            k_sgd = stack([c[1] for c in collected], self.devices)
            ts, goal, metrics = self._learn(ts, goal, data, k_sgd)
            losses.append(metrics)
        drained = self._on_each_compiled_once("drain", lambda i, s: self._drain[i](s), envs)
        totals = self._sum(stack([d[1] for d in drained], self.devices))
        losses = jax.tree.map(lambda *xs: np.mean(np.stack([np.asarray(x) for x in xs]), axis=0), *losses)
        states = DeviceStates(pieces=tuple(d[0] for d in drained), goal=goal)
        return ts, states, {"totals": totals, "losses": losses}

    def collect_epoch(self, ts: TrainingState, states: DeviceStates, keys: jax.Array):
        """The epoch's collections alone (no learning): for timing the update's share (benchmarks.scaling.devices)."""
        keys = self._device_keys(keys)
        envs = list(states.pieces)
        for _ in range(self.learner.iterations_per_epoch):
            envs, keys, _ = self._collect_all(ts, states.goal, envs, keys)
        jax.block_until_ready(envs)
        return ts, DeviceStates(pieces=tuple(envs), goal=states.goal)

    def env_levels(self, states: DeviceStates) -> dict:
        """This process's envs' terrain types and levels and randomisation levels as host arrays (envs,),
        in device order."""
        return host_levels([jax.device_get(s.curricula) for s in states.pieces])

    @staticmethod
    def goal_curriculum(states: DeviceStates) -> goal_curriculum.GoalCurriculumState:
        """The goal curriculum's state (the first device's copy; all are equal)."""
        return first_copy(states.goal)

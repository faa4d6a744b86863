"""Evaluation episodes on C MuJoCo spread over processes: ``python -m train.evaluate --backend c --workers N``.

On C MuJoCo (``hsa_mjx.sim.host_physics``) the episodes of one evaluation run one after another in one
process, so a CPU of many cores sits mostly idle. Here the episodes' keys are cut into ``N`` contiguous
shards, each played by its own process (spawned: no JAX state inherited) that loads the same run or
policy, and the traces are joined in the keys' order: each episode is the one a single process would
play with its key (the same goal, start and action noise), only its neighbours in the batch differ.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .rollout import rollout

_WORKER: dict[str, Any] = {}


def shards(keys: np.ndarray, workers: int) -> list[np.ndarray]:
    """``keys`` cut into at most ``workers`` contiguous, non-empty shards, in order."""
    return [part for part in np.array_split(np.asarray(keys), min(workers, len(keys))) if len(part)]


def joined(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The shards' traces as one batch, episodes in the shards' order (every trace has the episode axis first)."""
    return {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}


def _setup(load: Callable[[Any], tuple], spec: Any) -> None:
    _, env, policy, _, _ = load(spec)  # in the spawned process: the subject loaded as the parent did
    _WORKER.update(env=env, policy=policy)


def _play(keys: np.ndarray, goal_range: tuple[float, float], steps: int) -> dict[str, np.ndarray]:
    traces = rollout(_WORKER["env"], _WORKER["policy"], jnp.asarray(keys), jnp.asarray(goal_range, jnp.float32), steps)
    return {name: np.asarray(value) for name, value in jax.device_get(traces).items()}


def play(load: Callable[[Any], tuple], spec: Any, keys: np.ndarray, goal_range: tuple, steps: int, workers: int):
    """Each key's episode of ``spec``'s run or policy (an ``EvalSpec`` on the C backend, loaded in each
    process by ``load``: ``train.episodes.play.load_subject``), ``workers`` processes at once; the traces as
    ``train.episodes.rollout.rollout`` returns them, in the keys' order."""
    parts = shards(keys, workers)
    context = multiprocessing.get_context("spawn")
    one = dataclasses.replace(spec, workers=1)
    with ProcessPoolExecutor(len(parts), context, initializer=_setup, initargs=(load, one)) as pool:
        return joined(list(pool.map(_play, parts, [tuple(goal_range)] * len(parts), [steps] * len(parts))))

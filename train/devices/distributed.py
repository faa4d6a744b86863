"""Training over several processes (hosts): set-up, which process writes, and each process's share of keys.

One process per host, each driving its own local devices with ``pmap``; the ``pmap`` axis spans
the devices of every process, so the gradient, observation-statistics and curriculum reductions
of :mod:`train.learners.ppo.learner` already run over all of them (Brax's multi-host scheme). What differs from
one host: ``jax.distributed.initialize`` must run before any other JAX call, the envs are split
over the global device count, every process takes its own slice of the env and epoch keys, only
process 0 writes the run dir, and a stop request on any process stops all of them together.

How the processes find each other and join is ``train.devices.cluster``'s. Once joined, they check
that they run the same config on as many devices each.

With one process every function here is the plain single-host behaviour.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

import jax
import numpy as np


def _fingerprint(config: dict, local_devices: int) -> np.ndarray:
    """This process's config digest (32 bytes) and local device count, as one row to all-gather."""
    digest = hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).digest()
    return np.concatenate([np.frombuffer(digest, np.uint8).astype(np.int32), [local_devices]])


def disagreement(rows: np.ndarray) -> str | None:
    """What the processes' fingerprints (one row each, as :func:`_fingerprint` makes them) disagree
    on, or None."""
    problems = []
    if len({tuple(r[:-1]) for r in rows}) > 1:
        problems.append(f"configs differ (digest groups by process: {_groups([tuple(r[:-1]) for r in rows])})")
    if len({int(r[-1]) for r in rows}) > 1:
        problems.append(f"local device counts differ (by process: {[int(r[-1]) for r in rows]})")
    return "; ".join(problems) or None


def _groups(values: list) -> list[int]:
    """Each value's group number, in order of first appearance (which processes agree)."""
    first = {}
    return [first.setdefault(v, len(first)) for v in values]


def check_agreement(config: dict, local_devices: list) -> None:
    """ValueError on every process unless all run ``config`` on as many local devices (before any compile)."""
    if jax.process_count() == 1:
        return
    problem = disagreement(all_processes(_fingerprint(config, len(local_devices))))
    if problem:
        raise ValueError(f"the {jax.process_count()} processes must run one config on as many devices each: {problem}")


def is_main() -> bool:
    """Whether this process writes checkpoints, logs and plots (process 0)."""
    return jax.process_index() == 0


def global_device_count(local_devices: list) -> int:
    """Devices of all processes taking part (every process uses as many local devices as this one)."""
    return len(local_devices) * jax.process_count()


def process_share(keys: jax.Array, local_devices: list) -> jax.Array:
    """This process's part of keys made for every global device, shaped (local devices, per device, ...)."""
    per_device = keys.shape[0] // global_device_count(local_devices)
    shaped = keys.reshape((jax.process_count(), len(local_devices), per_device) + keys.shape[1:])
    return shaped[jax.process_index()]


def env_keys(key: jax.Array, num_envs: int, local_devices: list) -> jax.Array:
    """One key per env of the whole run, split from ``key``; this process's share, (local devices, envs / device, 2)."""
    return process_share(jax.random.split(key, num_envs), local_devices)


def epoch_keys(key: jax.Array, local_devices: list) -> jax.Array:
    """One key per global device, split from ``key``; this process's share, (local devices, 2)."""
    return process_share(jax.random.split(key, global_device_count(local_devices)), local_devices)[:, 0]


def all_devices(tree: Any) -> Any:
    """Host values with a leading axis over this process's devices, extended to every process's devices."""
    if jax.process_count() == 1:
        return tree
    from jax.experimental import multihost_utils

    return multihost_utils.process_allgather(tree, tiled=True)


def all_processes(values: np.ndarray) -> np.ndarray:
    """Every process's ``values`` stacked in process order, (processes, ...); ``values[None]`` with one."""
    if jax.process_count() == 1:
        return np.asarray(values)[None]
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(np.asarray(values)))


def any_process(flag: bool) -> bool:
    """True when ``flag`` is set on any process (a host-side all-gather; no communication with one process)."""
    if jax.process_count() == 1:
        return bool(flag)
    from jax.experimental import multihost_utils

    return bool(np.any(multihost_utils.process_allgather(np.asarray(flag))))

"""Training over several processes (hosts): set-up, which process writes, and each process's share of keys.

One process per host, each driving its own local devices with ``pmap``; the ``pmap`` axis spans
the devices of every process, so the gradient, observation-statistics and curriculum reductions
of :mod:`train.learners.ppo.learner` already run over all of them (Brax's multi-host scheme). What differs from
one host: ``jax.distributed.initialize`` must run before any other JAX call, the envs are split
over the global device count, every process takes its own slice of the env and epoch keys, only
process 0 writes the run dir, and a stop request on any process stops all of them together.

Processes find each other from flags (``--coordinator``, ``--num-processes``, ``--process-id``), the
``HSA_*`` variables, or, with neither, a cluster's own launcher: under ``srun`` (SLURM) or ``mpirun``
(Open MPI) with more than one task, ``jax.distributed.initialize()`` reads the job's variables.
Once joined, the processes check that they run the same config on as many devices each.

With one process every function here is the plain single-host behaviour.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np

ENV_VARS = {"coordinator": "HSA_COORDINATOR", "num_processes": "HSA_NUM_PROCESSES", "process_id": "HSA_PROCESS_ID"}


# A cluster launcher's variables: (the launcher, its task count, this task's index). JAX's
# auto-detection (jax.distributed.initialize() with no argument) reads the same ones.
LAUNCHERS = (
    ("slurm", "SLURM_STEP_NUM_TASKS", "SLURM_PROCID"),  # srun: one job step of N tasks
    ("openmpi", "OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"),  # mpirun
)


@dataclasses.dataclass(frozen=True)
class ClusterSpec:
    """Where the coordinator listens, how many processes take part and which one this is.

    ``coordinator`` None: the processes were started by ``launcher`` (``slurm``, ``openmpi``) and
    ``jax.distributed.initialize()`` finds the coordinator from its variables.
    """

    coordinator: str | None
    num_processes: int
    process_id: int
    launcher: str = "flags"


def _int_setting(value: int | str | None, flag: str, env_var: str) -> int | None:
    """An integer from a flag or environment variable (ValueError naming both when it is not one)."""
    if value is None or value == "":
        return None
    try:
        return int(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{flag} / {env_var} must be an integer, got {value!r}") from err


def resolve_spec(
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    environ: Mapping[str, str] | None = None,
) -> ClusterSpec | None:
    """The cluster from flags, else ``HSA_*`` environment variables; None when none is asked for."""
    environ = os.environ if environ is None else environ
    coordinator = coordinator or environ.get(ENV_VARS["coordinator"]) or None
    count = _int_setting(
        num_processes if num_processes is not None else environ.get(ENV_VARS["num_processes"]),
        "--num-processes",
        ENV_VARS["num_processes"],
    )
    index = _int_setting(
        process_id if process_id is not None else environ.get(ENV_VARS["process_id"]),
        "--process-id",
        ENV_VARS["process_id"],
    )
    if coordinator is None and count is None and index is None:
        return from_launcher(environ)
    if coordinator is None or count is None or index is None:
        raise ValueError(
            "several processes need all of --coordinator HOST:PORT, --num-processes N and "
            f"--process-id I (or {', '.join(ENV_VARS.values())}); got coordinator={coordinator!r}, "
            f"num_processes={count}, process_id={index}"
        )
    host, _, port = coordinator.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--coordinator must be HOST:PORT (process 0's address), got {coordinator!r}")
    if count < 1 or not 0 <= index < count:
        raise ValueError(f"need --num-processes >= 1 and 0 <= --process-id < --num-processes, got {count}, {index}")
    return ClusterSpec(coordinator, count, index)


def from_launcher(environ: Mapping[str, str]) -> ClusterSpec | None:
    """The cluster a launcher (``srun``, ``mpirun``) started with more than one task; None otherwise."""
    for launcher, count_var, index_var in LAUNCHERS:
        count = _int_setting(environ.get(count_var), launcher, count_var)
        if count is not None and count > 1:
            index = _int_setting(environ.get(index_var), launcher, index_var)
            if index is None or not 0 <= index < count:
                raise ValueError(f"{launcher} started {count} tasks but {index_var} is {environ.get(index_var)!r}")
            return ClusterSpec(None, count, index, launcher)
    return None


def initialize(spec: ClusterSpec | None) -> None:
    """Join the cluster with ``jax.distributed.initialize`` (call before any other JAX call); None: one host."""
    if spec is None:
        return
    if spec.coordinator is None:  # the launcher's variables say where and who (JAX's auto-detection)
        jax.distributed.initialize()
    else:
        jax.distributed.initialize(
            coordinator_address=spec.coordinator, num_processes=spec.num_processes, process_id=spec.process_id
        )
    if jax.process_count() != spec.num_processes:
        raise ValueError(f"expected {spec.num_processes} processes ({spec.launcher}), JAX joined {jax.process_count()}")
    # Open the collectives now, while the processes are together: a collective's first use waits only
    # 30 s for the others, and later set-up and compiles may keep one process longer than that.
    any_process(False)


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

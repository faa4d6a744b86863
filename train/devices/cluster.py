"""How the processes of a run find each other, and what a cluster's scheduler needs of them.

Processes find each other from flags (``--coordinator``, ``--num-processes``, ``--process-id``), the
``HSA_*`` variables, or, with neither, a cluster's own launcher: under ``srun`` (SLURM) or ``mpirun``
(Open MPI) with more than one task, the job's variables say how many and which one.

- **SLURM, several GPUs a task.** JAX's own detection gives each task the one GPU of its
  ``SLURM_LOCALID``; :func:`local_device_ids` gives a task every GPU it was allotted (one task a node
  with ``--gpus-per-node=4`` drives four), and one GPU a task when the tasks of a node share them.
- **Open MPI 5** has no ``OMPI_MCA_orte_hnp_uri``, where JAX looks for the coordinator: the task count
  and rank are read from ``OMPI_COMM_WORLD_*`` and the coordinator from ``HSA_COORDINATOR``
  (``mpirun -x HSA_COORDINATOR=host0:1234``); without it, a ValueError says so.
- **Requeue at the time limit.** With ``python -m train --requeue``, a run stopped by a signal before
  its end asks SLURM to requeue its job (``scontrol requeue``) once its checkpoint is written, when the
  job's time is nearly up (``SLURM_JOB_END_TIME``; always where SLURM does not say).
- **A requeued job before its first checkpoint** starts afresh in its run dir: the run dir records the
  job that made it (:func:`job_marker`), and only the same job, restarted (``SLURM_RESTART_COUNT``),
  may replace a run with no checkpoint; another job's run is refused as before.
"""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import time
from collections.abc import Callable, Mapping

import jax

from .distributed import any_process

ENV_VARS = {"coordinator": "HSA_COORDINATOR", "num_processes": "HSA_NUM_PROCESSES", "process_id": "HSA_PROCESS_ID"}
# A cluster launcher's variables: (the launcher, its task count, this task's index).
LAUNCHERS = (
    ("slurm", "SLURM_STEP_NUM_TASKS", "SLURM_PROCID"),  # srun: one job step of N tasks
    ("openmpi", "OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"),  # mpirun
)
OPEN_MPI_4_URI = "OMPI_MCA_orte_hnp_uri"  # where JAX reads an Open MPI job's coordinator (not set by Open MPI 5)
REQUEUE_WINDOW_S = 600  # a stop this close to the job's end is its time limit's: requeue


@dataclasses.dataclass(frozen=True)
class ClusterSpec:
    """Where the coordinator listens, how many processes take part and which one this is.

    ``coordinator`` None: the processes were started by ``launcher`` (``slurm``, ``openmpi``) and
    ``jax.distributed.initialize()`` finds the coordinator from its variables. ``local_device_ids``:
    the GPUs this process drives (None: JAX's choice).
    """

    coordinator: str | None
    num_processes: int
    process_id: int
    launcher: str = "flags"
    local_device_ids: tuple[int, ...] | None = None


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
    """The cluster from flags, else ``HSA_*`` environment variables, else a launcher's; None for one process."""
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
    if count is None and index is None:
        launched = from_launcher(environ, coordinator)
        if launched is not None or coordinator is None:
            return launched
    if coordinator is None or count is None or index is None:
        raise ValueError(
            "several processes need all of --coordinator HOST:PORT, --num-processes N and "
            f"--process-id I (or {', '.join(ENV_VARS.values())}); got coordinator={coordinator!r}, "
            f"num_processes={count}, process_id={index}"
        )
    _check_address(coordinator)
    if count < 1 or not 0 <= index < count:
        raise ValueError(f"need --num-processes >= 1 and 0 <= --process-id < --num-processes, got {count}, {index}")
    return ClusterSpec(coordinator, count, index)


def _check_address(coordinator: str) -> None:
    host, _, port = coordinator.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--coordinator must be HOST:PORT (process 0's address), got {coordinator!r}")


def from_launcher(environ: Mapping[str, str], coordinator: str | None = None) -> ClusterSpec | None:
    """The cluster a launcher (``srun``, ``mpirun``) started with more than one task; None otherwise.
    ``coordinator`` (``HSA_COORDINATOR``) is Open MPI 5's, which sets none that JAX can read."""
    for launcher, count_var, index_var in LAUNCHERS:
        count = _int_setting(environ.get(count_var), launcher, count_var)
        if count is None or count <= 1:
            continue
        index = _int_setting(environ.get(index_var), launcher, index_var)
        if index is None or not 0 <= index < count:
            raise ValueError(f"{launcher} started {count} tasks but {index_var} is {environ.get(index_var)!r}")
        if launcher == "slurm":
            return ClusterSpec(coordinator, count, index, launcher, local_device_ids(environ))
        if coordinator is None and OPEN_MPI_4_URI not in environ:
            raise ValueError(
                f"Open MPI started {count} tasks but sets no coordinator JAX can read (Open MPI 5 has no "
                f"{OPEN_MPI_4_URI}): give process 0's address, e.g. mpirun -x {ENV_VARS['coordinator']}=HOST:1234"
            )
        if coordinator is not None:
            _check_address(coordinator)
        return ClusterSpec(coordinator, count, index, launcher)
    return None


def _tasks_per_node(environ: Mapping[str, str]) -> int | None:
    """SLURM's tasks on this node (``SLURM_NTASKS_PER_NODE``, or this node's entry of ``4(x2),2``)."""
    text = environ.get("SLURM_NTASKS_PER_NODE") or environ.get("SLURM_STEP_TASKS_PER_NODE") or ""
    found = re.match(r"\s*(\d+)", text)
    return int(found.group(1)) if found else None


def local_device_ids(environ: Mapping[str, str]) -> tuple[int, ...] | None:
    """The GPUs a SLURM task drives, numbered as it sees them: all it was allotted (``CUDA_VISIBLE_DEVICES``)
    when it has them to itself, its ``SLURM_LOCALID``'s alone when the node's tasks see the same GPUs;
    None where SLURM says nothing of GPUs."""
    visible = [v for v in environ.get("CUDA_VISIBLE_DEVICES", "").split(",") if v.strip()]
    if not visible:
        return None
    tasks = _tasks_per_node(environ) or 1
    on_node = _int_setting(environ.get("SLURM_GPUS_ON_NODE"), "slurm", "SLURM_GPUS_ON_NODE")
    shared = tasks > 1 and (len(visible) == on_node if on_node else len(visible) == tasks)
    if shared:  # every task of the node sees every GPU: one each, by its rank on the node
        local = _int_setting(environ.get("SLURM_LOCALID"), "slurm", "SLURM_LOCALID") or 0
        return (local,)
    return tuple(range(len(visible)))


def initialize(spec: ClusterSpec | None) -> None:
    """Join the cluster with ``jax.distributed.initialize`` (call before any other JAX call); None: one host."""
    if spec is None:
        return
    devices = {"local_device_ids": list(spec.local_device_ids)} if spec.local_device_ids is not None else {}
    if spec.coordinator is None:  # the launcher's variables say where and who (JAX's auto-detection)
        jax.distributed.initialize(**devices)
    else:
        jax.distributed.initialize(
            coordinator_address=spec.coordinator,
            num_processes=spec.num_processes,
            process_id=spec.process_id,
            **devices,
        )
    if jax.process_count() != spec.num_processes:
        raise ValueError(f"expected {spec.num_processes} processes ({spec.launcher}), JAX joined {jax.process_count()}")
    # Open the collectives now, while the processes are together: a collective's first use waits only
    # 30 s for the others, and later set-up and compiles may keep one process longer than that.
    any_process(False)


# ----- the scheduler: requeue, and which job made a run dir ---------------------------------
def job_marker(environ: Mapping[str, str] | None = None) -> dict[str, str] | None:
    """What a run dir records of the job that started it (``job.json``): its SLURM job id; None outside SLURM."""
    environ = os.environ if environ is None else environ
    job = environ.get("SLURM_JOB_ID")
    return {"slurm_job_id": job} if job else None


def restarted_job(marker: Mapping[str, str] | None, environ: Mapping[str, str] | None = None) -> bool:
    """Whether this process is the job that wrote ``marker``, requeued (``SLURM_RESTART_COUNT`` >= 1)."""
    environ = os.environ if environ is None else environ
    restarts = _int_setting(environ.get("SLURM_RESTART_COUNT"), "slurm", "SLURM_RESTART_COUNT") or 0
    return bool(marker) and restarts >= 1 and marker.get("slurm_job_id") == environ.get("SLURM_JOB_ID")


def should_requeue(environ: Mapping[str, str] | None = None, now: float | None = None) -> bool:
    """Whether a stopped run's SLURM job is at its time limit (within ``REQUEUE_WINDOW_S`` of
    ``SLURM_JOB_END_TIME``, or that time unknown); never outside SLURM."""
    environ = os.environ if environ is None else environ
    if not environ.get("SLURM_JOB_ID"):
        return False
    end = _int_setting(environ.get("SLURM_JOB_END_TIME"), "slurm", "SLURM_JOB_END_TIME")
    return end is None or end - (time.time() if now is None else now) <= REQUEUE_WINDOW_S


def requeue(environ: Mapping[str, str] | None = None, run: Callable = subprocess.run) -> str:
    """Ask SLURM to requeue this job (``scontrol requeue``); the line to print (a warning on failure)."""
    environ = os.environ if environ is None else environ
    job = environ["SLURM_JOB_ID"]
    try:
        done = run(["scontrol", "requeue", job], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as err:
        return f"warning: could not requeue SLURM job {job}: {err}"
    if done.returncode:
        return f"warning: scontrol requeue {job} failed: {(done.stderr or '').strip()}"
    return f"requeued SLURM job {job}: it resumes from the checkpoint just written"

"""Several processes: who joins (flags, variables, a cluster's launcher), whether they agree, their keys.

The training of two processes itself is in ``tests/test_multi_device.py`` (two CPU processes over Gloo).
"""

import json
import subprocess

import jax
import numpy as np
import pytest

from train.devices import cluster, distributed


def test_cluster_spec_from_flags_or_environment():
    assert cluster.resolve_spec(environ={}) is None
    env = {"HSA_COORDINATOR": "10.0.0.1:1234", "HSA_NUM_PROCESSES": "4", "HSA_PROCESS_ID": "3"}
    assert cluster.resolve_spec(environ=env) == cluster.ClusterSpec("10.0.0.1:1234", 4, 3)
    assert cluster.resolve_spec(process_id=0, environ=env).process_id == 0  # a flag wins
    for kwargs, match in (
        ({"coordinator": "h:1", "num_processes": 2}, "--process-id"),
        ({"coordinator": "host", "num_processes": 2, "process_id": 0}, "HOST:PORT"),
        ({"coordinator": "h:1", "num_processes": 2, "process_id": 2}, "0 <= --process-id"),
    ):
        with pytest.raises(ValueError, match=match):
            cluster.resolve_spec(**kwargs, environ={})
    with pytest.raises(ValueError, match="HSA_NUM_PROCESSES must be an integer"):
        cluster.resolve_spec(environ={**env, "HSA_NUM_PROCESSES": "four"})


def test_one_process_keys_are_the_single_host_split():
    devices, key = jax.local_devices()[:1], jax.random.PRNGKey(7)
    np.testing.assert_array_equal(distributed.env_keys(key, 6, devices), jax.random.split(key, 6).reshape(1, 6, 2))
    np.testing.assert_array_equal(distributed.epoch_keys(key, devices), jax.random.split(key, 1))
    assert distributed.is_main() and distributed.any_process(True) and not distributed.any_process(False)


def test_cluster_launchers_are_read_when_no_flag_or_variable_is_given():
    slurm = {"SLURM_JOB_ID": "7", "SLURM_STEP_NUM_TASKS": "4", "SLURM_PROCID": "2"}
    assert cluster.resolve_spec(environ=slurm) == cluster.ClusterSpec(None, 4, 2, "slurm")
    mpi = {"OMPI_COMM_WORLD_SIZE": "2", "OMPI_COMM_WORLD_RANK": "1", cluster.OPEN_MPI_4_URI: "1.2.3.4:5"}  # 4.x
    assert cluster.resolve_spec(environ=mpi) == cluster.ClusterSpec(None, 2, 1, "openmpi")
    assert cluster.resolve_spec(environ={**slurm, "SLURM_STEP_NUM_TASKS": "1"}) is None  # one task: one host
    flags = cluster.resolve_spec("h:1", 2, 0, environ=slurm)
    assert flags == cluster.ClusterSpec("h:1", 2, 0)  # flags win over the launcher
    with pytest.raises(ValueError, match="SLURM_PROCID"):
        cluster.resolve_spec(environ={**slurm, "SLURM_PROCID": "4"})


def test_processes_that_disagree_on_config_or_devices_are_named():
    config = {"run": {"seed": 0}}
    same = np.stack([distributed._fingerprint(config, 1)] * 3)
    assert distributed.disagreement(same) is None
    other = np.stack([same[0], distributed._fingerprint({"run": {"seed": 1}}, 1), distributed._fingerprint(config, 2)])
    problem = distributed.disagreement(other)
    assert "configs differ (digest groups by process: [0, 1, 0])" in problem
    assert "local device counts differ (by process: [1, 1, 2])" in problem
    distributed.check_agreement(config, jax.local_devices()[:1])  # one process: nothing to compare


def test_slurm_tasks_drive_every_gpu_they_were_given():
    """JAX alone gives a SLURM task the GPU of its SLURM_LOCALID: a task with a node's GPUs drives them all."""
    node = {"SLURM_STEP_NUM_TASKS": "2", "SLURM_PROCID": "1", "SLURM_NTASKS_PER_NODE": "1", "SLURM_LOCALID": "0"}
    node |= {"CUDA_VISIBLE_DEVICES": "0,1,2,3", "SLURM_GPUS_ON_NODE": "4"}
    assert cluster.resolve_spec(environ=node).local_device_ids == (0, 1, 2, 3)
    per_gpu = {**node, "SLURM_NTASKS_PER_NODE": "4", "SLURM_LOCALID": "2"}
    assert cluster.local_device_ids({**per_gpu, "CUDA_VISIBLE_DEVICES": "2"}) == (0,)  # bound: its one GPU
    assert cluster.local_device_ids(per_gpu) == (2,)  # every task sees the node's four: its own
    pairs = {**node, "SLURM_NTASKS_PER_NODE": "", "SLURM_STEP_TASKS_PER_NODE": "2(x2)", "CUDA_VISIBLE_DEVICES": "4,5"}
    assert cluster.local_device_ids(pairs) == (0, 1)  # two tasks of a node, two GPUs each
    assert cluster.local_device_ids({}) is None


def test_open_mpi_5_takes_the_coordinator_it_does_not_set():
    mpi5 = {"OMPI_COMM_WORLD_SIZE": "2", "OMPI_COMM_WORLD_RANK": "1"}
    with pytest.raises(ValueError, match="HSA_COORDINATOR=HOST"):
        cluster.resolve_spec(environ=mpi5)
    assert cluster.resolve_spec(environ={**mpi5, "HSA_COORDINATOR": "h0:1234"}) == cluster.ClusterSpec(
        "h0:1234", 2, 1, "openmpi"
    )
    assert cluster.resolve_spec(environ={**mpi5, cluster.OPEN_MPI_4_URI: "x"}) == cluster.ClusterSpec(
        None, 2, 1, "openmpi"
    )


def test_a_stopped_slurm_job_is_requeued_at_its_time_limit_only():
    env = {"SLURM_JOB_ID": "42", "SLURM_JOB_END_TIME": "10000"}
    assert cluster.should_requeue(env, now=9700) and not cluster.should_requeue(env, now=100)  # a cancel, say
    assert cluster.should_requeue({"SLURM_JOB_ID": "42"}) and not cluster.should_requeue({})
    calls = []

    def scontrol(cmd: list, **kwargs) -> subprocess.CompletedProcess:
        calls.append(cmd)
        return subprocess.CompletedProcess(cmd, 0 if len(calls) == 1 else 1, "", "Invalid job id")

    assert "requeued SLURM job 42" in cluster.requeue(env, run=scontrol) and calls == [["scontrol", "requeue", "42"]]
    assert "failed: Invalid job id" in cluster.requeue(env, run=scontrol)


def test_the_same_job_requeued_before_a_checkpoint_starts_afresh(tmp_path, monkeypatch):
    from train.run.folder import prepare_run_dir

    monkeypatch.setenv("SLURM_JOB_ID", "7")
    monkeypatch.delenv("SLURM_RESTART_COUNT", raising=False)
    run = tmp_path / "run"
    prepare_run_dir(run, {"a": 1}, resume=False)
    assert json.loads((run / "job.json").read_text()) == {"slurm_job_id": "7"}
    with pytest.raises(ValueError, match="already holds a run"):  # the same job, not requeued: a mistake
        prepare_run_dir(run, {"a": 1}, resume=False)
    monkeypatch.setenv("SLURM_RESTART_COUNT", "1")
    assert prepare_run_dir(run, {"a": 2}, resume=False) is None and "a: 2" in (run / "config.yaml").read_text()
    assert prepare_run_dir(run, {"a": 3}, resume=True) is None  # nothing to resume yet: afresh as well
    monkeypatch.setenv("SLURM_JOB_ID", "8")  # another job's run is refused as before
    with pytest.raises(ValueError, match="already holds a run"):
        prepare_run_dir(run, {"a": 1}, resume=False)

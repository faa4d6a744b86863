"""Several processes: who joins (flags, variables, a cluster's launcher), whether they agree, their keys.

The training of two processes itself is in ``tests/test_multi_device.py`` (two CPU processes over Gloo).
"""

import jax
import numpy as np
import pytest

from train.devices import distributed


def test_cluster_spec_from_flags_or_environment():
    assert distributed.resolve_spec(environ={}) is None
    env = {"HSA_COORDINATOR": "10.0.0.1:1234", "HSA_NUM_PROCESSES": "4", "HSA_PROCESS_ID": "3"}
    assert distributed.resolve_spec(environ=env) == distributed.ClusterSpec("10.0.0.1:1234", 4, 3)
    assert distributed.resolve_spec(process_id=0, environ=env).process_id == 0  # a flag wins
    for kwargs, match in (
        ({"coordinator": "h:1", "num_processes": 2}, "--process-id"),
        ({"coordinator": "host", "num_processes": 2, "process_id": 0}, "HOST:PORT"),
        ({"coordinator": "h:1", "num_processes": 2, "process_id": 2}, "0 <= --process-id"),
    ):
        with pytest.raises(ValueError, match=match):
            distributed.resolve_spec(**kwargs, environ={})
    with pytest.raises(ValueError, match="HSA_NUM_PROCESSES must be an integer"):
        distributed.resolve_spec(environ={**env, "HSA_NUM_PROCESSES": "four"})


def test_one_process_keys_are_the_single_host_split():
    devices, key = jax.local_devices()[:1], jax.random.PRNGKey(7)
    np.testing.assert_array_equal(distributed.env_keys(key, 6, devices), jax.random.split(key, 6).reshape(1, 6, 2))
    np.testing.assert_array_equal(distributed.epoch_keys(key, devices), jax.random.split(key, 1))
    assert distributed.is_main() and distributed.any_process(True) and not distributed.any_process(False)


def test_cluster_launchers_are_read_when_no_flag_or_variable_is_given():
    slurm = {"SLURM_JOB_ID": "7", "SLURM_STEP_NUM_TASKS": "4", "SLURM_PROCID": "2"}
    assert distributed.resolve_spec(environ=slurm) == distributed.ClusterSpec(None, 4, 2, "slurm")
    mpi = {"OMPI_COMM_WORLD_SIZE": "2", "OMPI_COMM_WORLD_RANK": "1"}
    assert distributed.resolve_spec(environ=mpi) == distributed.ClusterSpec(None, 2, 1, "openmpi")
    assert distributed.resolve_spec(environ={**slurm, "SLURM_STEP_NUM_TASKS": "1"}) is None  # one task: one host
    flags = distributed.resolve_spec("h:1", 2, 0, environ=slurm)
    assert flags == distributed.ClusterSpec("h:1", 2, 0)  # flags win over the launcher
    with pytest.raises(ValueError, match="SLURM_PROCID"):
        distributed.resolve_spec(environ={**slurm, "SLURM_PROCID": "4"})


def test_processes_that_disagree_on_config_or_devices_are_named():
    config = {"run": {"seed": 0}}
    same = np.stack([distributed._fingerprint(config, 1)] * 3)
    assert distributed.disagreement(same) is None
    other = np.stack([same[0], distributed._fingerprint({"run": {"seed": 1}}, 1), distributed._fingerprint(config, 2)])
    problem = distributed.disagreement(other)
    assert "configs differ (digest groups by process: [0, 1, 0])" in problem
    assert "local device counts differ (by process: [1, 1, 2])" in problem
    distributed.check_agreement(config, jax.local_devices()[:1])  # one process: nothing to compare

"""The deployment loop: the observation it builds from sensors, latency, the command line."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.deploy import loop, policy_file
from hsa_mjx.deploy.__main__ import main
from hsa_mjx.task.observation import observation_labels


def test_the_loop_builds_the_envs_observation_from_sensor_readings():
    meta = policy_file.read_meta(policy_file.locate("flat"))
    config, labels, goal_range = loop.policy_env(meta)
    assert goal_range == (1.5, 4.5)  # the curriculum's target, not its start
    env = hsa_mjx.make_env(
        config, physics__backend="c", observation__servo_targets=True, observation__clock_period_s=2.0
    )
    all_labels = list(observation_labels(env.config.observation))
    state, step = env.reset(jax.random.PRNGKey(2)), jax.jit(env.step)
    for action in jax.random.uniform(jax.random.PRNGKey(3), (5, 8), minval=-1, maxval=1):
        state = step(state, action)
    d, idx = state.pipeline_state.physics, env.index
    readings = loop.Readings(
        np.asarray(d.qpos[idx.joint_qpos]), np.asarray(d.qvel[idx.joint_qvel]), np.asarray(d.xpos[idx.block_body])
    )
    velocity = np.asarray(d.qvel[idx.block_qvel[:, None] + np.arange(3)]).mean(axis=0)  # exact, as the env reads it
    entries = loop.observation_entries(
        readings,
        velocity,
        np.asarray(state.pipeline_state.task.goal_xy),
        np.asarray(d.ctrl[idx.servo_ids]),
        5 * env.dt,
        env.config,
    )
    obs = np.asarray([entries[label] for label in all_labels], np.float32)
    np.testing.assert_allclose(obs, np.asarray(state.obs), rtol=1e-5, atol=1e-5)
    assert set(labels) <= set(all_labels)


def test_latency_holds_the_servo_targets_for_the_set_ticks():
    config = hsa_mjx.build_config("flat")
    readings = loop.Readings(np.zeros(8), np.zeros(8), np.array([[-0.2, 0, 0.1], [0.2, 0, 0.1]]))
    labels = list(observation_labels(config.observation))
    moved = []
    for latency in (0, 2):
        controller = loop.Controller(lambda obs: np.ones(8), labels, config, 8, latency)
        moved.append([float(np.abs(controller.act(readings, np.array([2.0, 0.0]))).max()) for _ in range(4)])
    step = config.control.max_increment
    np.testing.assert_allclose(moved, [[step, 2 * step, 3 * step, 4 * step], [0, 0, step, 2 * step]], rtol=1e-6)


def test_deploy_reaches_goals_and_refuses_what_it_cannot_run(capsys, tmp_path):
    assert main(["--policy", "flat", "--goal", "1.5", "0.5"]) == 0
    assert "1 of 1 goals reached" in capsys.readouterr().out
    assert main(["--policy", "rough"]) == 2
    assert "height scan" in capsys.readouterr().err
    assert main(["--policy", "flat", "--latency-ms", "30"]) == 2
    assert "whole number" in capsys.readouterr().err
    assert main(["--policy", "flat", "--onnx"]) == 2
    assert "policy.onnx not found" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([])  # --policy is required

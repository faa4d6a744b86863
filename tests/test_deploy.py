"""The deployment loop: the observation it builds from sensors, latency, the command line."""

from __future__ import annotations

import dataclasses
import json
import shutil

import jax
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.deploy import loop, policy_file
from hsa_mjx.deploy.__main__ import main
from hsa_mjx.task.observation import observation_labels
from hsa_mjx.task.randomization import FIELDS


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


def test_the_history_input_is_the_same_rule_in_the_env_and_in_the_loop():
    env = hsa_mjx.make_env("flat", physics__backend="c", observation__servo_targets=True, observation__history_steps=2)
    labels = list(observation_labels(env.config.observation))
    core = 24 + 8  # the original's slots and the servo targets; a row adds the 8 actions
    assert len(labels) == env.observation_size == core + 2 * (core + 8) and labels[core] == "prev1_hinge_angle_0"
    actions = np.asarray(jax.random.uniform(jax.random.PRNGKey(1), (3, 8), minval=-1.5, maxval=1.5))
    states, step = [env.reset(jax.random.PRNGKey(0))], jax.jit(env.step)
    assert not np.any(np.asarray(states[0].obs)[core:])  # an episode starts with zero rows
    for action in actions:
        states.append(step(states[-1], action))
    obs = [np.asarray(s.obs) for s in states]
    clipped = np.clip(actions, -1, 1)
    expected = np.concatenate([obs[2][:core], clipped[2], obs[1][:core], clipped[1]])
    np.testing.assert_allclose(obs[3][core:], expected, rtol=1e-6)
    loop.check_deployable(env.config, labels)  # what an export of this policy lists, the loop can feed
    controller = loop.Controller(lambda o: actions[len(seen) - 1], labels, env.config, 8)
    readings = loop.Readings(np.zeros(8), np.zeros(8), np.array([[-0.2, 0, 0.1], [0.2, 0, 0.1]]))
    seen = []
    for _ in range(3):
        seen.append(controller.observe(readings, np.array([2.0, 0.0])))
        controller.act(readings, np.array([2.0, 0.0]))  # observes again, then records this tick's action
    last = controller.observe(readings, np.array([2.0, 0.0]))
    assert last.shape == (len(labels),)
    np.testing.assert_allclose(last[core : 2 * core + 8], np.concatenate([seen[-1][:core], clipped[2]]), atol=1e-6)
    with pytest.raises(ValueError, match="history slots"):
        loop.check_deployable(env.config, labels[:core] + labels[core + 40 :] + labels[core : core + 40])
    path = hsa_mjx.build_config(
        "flat",
        scene="terrain",
        terrain__reachability__enabled=True,
        terrain__reachability__goal_sites=1,
        goal__mode="radial",
        reward__progress="geodesic",
        observation__path_direction=True,
    )
    with pytest.raises(ValueError, match="path direction.*observation.path_direction"):
        loop.check_deployable(path, list(observation_labels(path.observation)))


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
    late = tmp_path / "late"  # a policy trained with one tick of latency (dfr05sr's PWM frame) plays with it
    shutil.copytree(policy_file.shipped()["flat_st3215"], late)
    meta = json.loads((late / "policy.json").read_text())
    meta["config"]["env"]["randomization"]["latency_steps"] = [1, 1]
    (late / "policy.json").write_text(json.dumps(meta))
    assert main(["--policy", str(late), "--goal", "0.5", "0", "--max-steps", "2"]) == 0
    assert "latency 1 ticks" in capsys.readouterr().out
    assert main(["--policy", "rough"]) == 2
    assert "height scan" in capsys.readouterr().err
    assert main(["--policy", "flat", "--latency-ms", "30"]) == 2
    assert "whole number" in capsys.readouterr().err
    assert main(["--policy", "flat", "--onnx"]) == 2
    assert "policy.onnx not found" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([])  # --policy is required


def _captured_fields(env, state) -> dict:
    """The model fields the env's step hands its physics for this episode (a physics that records them)."""
    captured = {}

    def record(data, targets, fields):
        captured.update(jax.device_get(fields))
        return env._simulate(data, targets, {})

    env.step_with(record, state, np.zeros(8, np.float32))
    return captured


def test_simulated_robot_perturbation_writes_the_fields_the_env_randomises():
    from hsa_mjx.deploy.perturbation import ModelPerturbation

    perturbation = ModelPerturbation(
        friction=0.3, block_mass=1.4, hsa_stiffness=0.5, hsa_damping=1.5, servo_gain=0.6, servo_torque_limit=0.5
    )
    config = loop.policy_env(policy_file.read_meta(policy_file.locate("flat")))[0]
    mj_model, index = loop.load_model(config)
    robot = loop.SimulatedRobot(mj_model, index, config, perturbation=perturbation)
    # the env drawing exactly these values (every range [v, v]) on the same model
    env = hsa_mjx.make_env(config, physics__backend="c", randomization=dataclasses.asdict(perturbation.randomization()))
    expected = _captured_fields(env, env.reset(jax.random.PRNGKey(0)))
    assert set(expected) == set(FIELDS) - {"dof_damping", "dof_frictionloss", "dof_armature"}  # all but a DC servo's
    for name, value in expected.items():
        np.testing.assert_allclose(getattr(robot.model, name), value, rtol=1e-6, err_msg=name)
        assert not np.allclose(getattr(mj_model, name), value), name  # changed, and in a copy only
    assert robot.model.actuator_forcelimited[index.servo_ids].all() and not mj_model.actuator_forcelimited.any()
    np.testing.assert_allclose(robot.model.body_mass[index.block_body], 1.4 * mj_model.body_mass[index.block_body])
    # the training model: the model itself
    assert loop.SimulatedRobot(mj_model, index, config, perturbation=ModelPerturbation()).model is mj_model


def test_simulated_robot_scales_each_foots_friction_and_anisotropy_as_the_env_does():
    from hsa_mjx.deploy.perturbation import ModelPerturbation

    config = loop.policy_env(policy_file.read_meta(policy_file.locate("flat")))[0]
    mj_model, index = loop.load_model(config)
    feet, nominal = index.foot_pairs, mj_model.pair_friction[index.foot_pairs, :2]
    lower = np.argmin(nominal, axis=1)
    # the same value on every foot: the env drawing exactly it writes the same pair frictions
    same = ModelPerturbation(foot_friction=(0.5,) * 4, foot_anisotropy=(2.0,) * 4)
    env = hsa_mjx.make_env(config, physics__backend="c", randomization=dataclasses.asdict(same.randomization()))
    expected = _captured_fields(env, env.reset(jax.random.PRNGKey(0)))
    assert set(expected) == {"pair_friction"}
    robot = loop.SimulatedRobot(mj_model, index, config, perturbation=same)
    np.testing.assert_allclose(robot.model.pair_friction, expected["pair_friction"], rtol=1e-6)
    # one foot alone: its two sliding coefficients scaled, the other feet as trained
    slick = loop.SimulatedRobot(mj_model, index, config, perturbation=ModelPerturbation(foot_friction=(0.3, 1, 1, 1)))
    np.testing.assert_allclose(slick.model.pair_friction[feet[0], :2], 0.3 * nominal[0], rtol=1e-6)
    np.testing.assert_allclose(slick.model.pair_friction[feet[1:], :2], nominal[1:], rtol=1e-6)
    # the anisotropy raises the lower coefficient alone: x2.1 makes every foot grip the same both ways
    even = ModelPerturbation(foot_anisotropy=(2.1,) * 4)
    pairs = loop.SimulatedRobot(mj_model, index, config, perturbation=even).model.pair_friction[feet, :2]
    np.testing.assert_allclose(pairs[np.arange(4), lower], 2.1 * nominal[np.arange(4), lower], rtol=1e-6)
    np.testing.assert_allclose(pairs[np.arange(4), 1 - lower], nominal[np.arange(4), 1 - lower], rtol=1e-6)


def test_deploy_runs_a_perturbed_robot_and_refuses_values_outside_the_ranges(capsys):
    args = ["--policy", "flat_dr", "--goal", "1.5", "0.5", "--max-steps", "40"]
    assert main([*args, "--friction", "0.3", "--servo-gain", "0.6", "--servo-torque-limit", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "a robot with friction x0.3, servo_gain x0.6, servo_torque_limit 0.5 N m" in out
    assert main([*args, "--foot-friction", "0.3", "1", "1", "1"]) == 0
    assert "a robot with foot_friction x0.3/1/1/1" in capsys.readouterr().out
    for flag, value, message in (
        ("--friction", "5", "friction must be in [0.1, 3], got 5.0"),
        ("--block-mass", "0.1", "block_mass must be in [0.5, 2], got 0.1"),
        ("--servo-torque-limit", "0", "servo_torque_limit must be in [0.05, 5], got 0.0"),
        ("--foot-anisotropy", "1 1 1 4", "foot_anisotropy must be in [0.1, 3], got (1.0, 1.0, 1.0, 4.0)"),
    ):
        assert main([*args, flag, *value.split()]) == 2
        assert message in capsys.readouterr().err

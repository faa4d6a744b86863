"""Velocities as a robot measures them (``observation.velocity: differenced``): a position tracker's noisy
readings differenced over one control step, in the env and in the deployment loop alike."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.deploy import loop
from hsa_mjx.task import observation

JITTER = 0.01  # m: a tracker's +-1 cm
TRACKED = {"observation.velocity": "differenced", "observation.noise.position": JITTER}


def _slots(config) -> tuple[list[int], list[int]]:
    """Observation indices of the position (x, y) and velocity (x, y) entries."""
    labels = list(observation.observation_labels(config.observation))
    return [labels.index("robot_x"), labels.index("robot_y")], [labels.index("block_vx"), labels.index("block_vy")]


def test_env_velocity_is_the_difference_of_noisy_tracker_readings():
    env = hsa_mjx.make_env("flat", physics__backend="jax", **TRACKED)
    position, velocity = _slots(env.config)
    step, state = jax.jit(env.step), jax.jit(env.reset)(jax.random.PRNGKey(0))
    assert np.all(np.asarray(state.obs)[velocity] == 0.0)  # no velocity before a second reading
    obs, true_xy, true_v = [np.asarray(state.obs)], [], []
    for action in np.random.default_rng(0).uniform(-1, 1, (8, 8)).astype(np.float32):
        state = step(state, action)
        obs.append(np.asarray(state.obs))
        true_xy.append(np.asarray(observation.robot_xy(state.pipeline_state.physics, env.index)))
        true_v.append(np.asarray(observation.base_velocity(state.pipeline_state.physics, env.index))[:2])
    obs = np.stack(obs)
    differenced = np.diff(obs[:, position], axis=0) / env.config.dt
    np.testing.assert_allclose(obs[1:, velocity], differenced, atol=1e-3)
    jitter = np.abs(obs[1:, position] - np.stack(true_xy))
    assert jitter.max() <= JITTER + 1e-6 and jitter.max() > 0.2 * JITTER  # each reading carries the jitter
    assert np.sqrt(np.mean((obs[1:, velocity] - np.stack(true_v)) ** 2)) > 0.1  # m/s: +-1 cm over 20 ms
    moved = env.set_goal(state, jnp.asarray([1.0, 1.0]))  # a new goal takes no new reading
    np.testing.assert_array_equal(np.asarray(moved.obs)[velocity + position], obs[-1][velocity + position])


def test_without_jitter_the_tracker_reads_the_robot_and_its_mean_velocity():
    env = hsa_mjx.make_env("flat", physics__backend="jax", **{**TRACKED, "observation.noise.position": 0.0})
    position, velocity = _slots(env.config)
    state = jax.jit(env.reset)(jax.random.PRNGKey(1))
    before = np.asarray(observation.robot_xy(state.pipeline_state.physics, env.index))
    state = jax.jit(env.step)(state, jnp.ones(8))
    after = np.asarray(observation.robot_xy(state.pipeline_state.physics, env.index))
    np.testing.assert_allclose(np.asarray(state.obs)[position], after, atol=1e-6)
    np.testing.assert_allclose(np.asarray(state.obs)[velocity], (after - before) / env.config.dt, atol=1e-3)


def test_deployment_loop_differences_the_same_noisy_readings():
    env = hsa_mjx.make_env("flat", **TRACKED)
    labels = list(observation.observation_labels(env.config.observation))
    position, velocity = _slots(env.config)
    robot = loop.SimulatedRobot(env.robot.mj_model, env.index, env.config)
    controller = loop.Controller(lambda obs: np.ones(8), labels, env.config, 8, seed=3)
    assert controller.tracker_noise == JITTER  # the policy's own tracker
    seen, exact = [], []
    for _ in range(6):
        readings = robot.read()
        robot.command(controller.act(readings, np.array([2.0, 0.0])))
        seen.append(controller.last_obs.copy())  # what the policy saw this tick
        exact.append(readings.block_positions[:, :2].mean(axis=0))
    seen = np.stack(seen)
    np.testing.assert_allclose(seen[1:, velocity], np.diff(seen[:, position], axis=0) / env.config.dt, atol=1e-3)
    assert np.all(seen[0, velocity] == 0.0)
    assert 0 < np.abs(seen[:, position] - np.stack(exact)).max() <= JITTER + 1e-6
    with pytest.raises(ValueError, match="observation.velocity"):
        hsa_mjx.make_env("flat", **{"observation.velocity": "encoder"})

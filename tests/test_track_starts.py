"""Spiral starts along the track (goal.track_starts): the pose moves, the start draw, the config
checks and the evaluation's override. Pure functions; the env-level reset is in test_terrain_env."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import hsa_mjx.config
from hsa_mjx import pose
from hsa_mjx.config import GoalConfig
from hsa_mjx.task import goals
from train.episodes.policy_sources import evaluation_env_config


def _rotation(quat) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, np.float64))
    return mat.reshape(3, 3)


def test_yaw_quaternion_turns_x_about_z_like_mujoco():
    for yaw in (0.0, 0.7, -2.5, np.pi):
        r = _rotation(pose.yaw_quaternion(jnp.float32(yaw)))
        np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [np.cos(yaw), np.sin(yaw), 0.0], atol=1e-6)
        np.testing.assert_allclose(r @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-6)


def test_quaternion_product_composes_rotations():
    a = jnp.asarray([0.9, 0.1, -0.3, 0.2]) / jnp.linalg.norm(jnp.asarray([0.9, 0.1, -0.3, 0.2]))
    b = jnp.asarray([0.5, 0.5, 0.5, 0.5])
    np.testing.assert_allclose(_rotation(pose.quaternion_product(a, b)), _rotation(a) @ _rotation(b), atol=1e-6)


def test_move_free_joints_is_rigid_and_lands_the_centre_on_the_target():
    # two free joints (the blocks) around centre (0.1, 0), a hinge value between them untouched
    qpos = jnp.asarray([-0.1, 0.0, 0.2, 1, 0, 0, 0, 0.33, 0.3, 0.0, 0.2, 1, 0, 0, 0], jnp.float32)
    addresses = np.array([0, 8])
    centre, target, yaw = jnp.array([0.1, 0.0]), jnp.array([2.0, -1.0]), jnp.float32(np.pi / 2)
    moved = np.asarray(pose.move_free_joints(qpos, addresses, centre, target, yaw))
    np.testing.assert_allclose(moved[[0, 1]], [2.0, -1.2], atol=1e-6)  # block A: 0.2 m behind, now along -y
    np.testing.assert_allclose(moved[[8, 9]], [2.0, -0.8], atol=1e-6)
    np.testing.assert_allclose(moved[[2, 10]], 0.2)  # heights: the caller's (spawn height)
    np.testing.assert_allclose(moved[7], 0.33)  # not a free joint: untouched
    np.testing.assert_allclose(_rotation(moved[3:7]) @ [1.0, 0, 0], [0.0, 1.0, 0.0], atol=1e-6)


def test_track_start_zero_is_the_original_start_and_others_face_the_next_checkpoint():
    checkpoints = jnp.asarray(goals.spiral_checkpoints(GoalConfig(num_checkpoints=20)))
    origin = jnp.array([0.01, 0.0])
    draws = jax.vmap(lambda k: goals.track_start(k, checkpoints, 5, origin))(
        jax.random.split(jax.random.PRNGKey(0), 400)
    )
    index, start, yaw = (np.asarray(x) for x in draws)
    assert set(index.tolist()) == set(range(6))  # uniform over 0..5, nothing beyond
    first = index == 0
    np.testing.assert_allclose(start[first], np.broadcast_to(origin, start[first].shape))
    np.testing.assert_allclose(yaw[first], 0.0)
    later = ~first
    np.testing.assert_allclose(start[later], np.asarray(checkpoints)[index[later] - 1], atol=1e-6)
    ahead = np.asarray(checkpoints)[index[later]] - start[later]
    np.testing.assert_allclose(
        np.stack([np.cos(yaw[later]), np.sin(yaw[later])], 1),
        ahead / np.linalg.norm(ahead, axis=1, keepdims=True),
        atol=1e-5,
    )
    # a given index gives the start a draw of that index gives, whatever the key
    for k in (0, 3, 5, 12):
        given = goals.track_start(jax.random.PRNGKey(k), checkpoints, 5, origin, jnp.asarray(k))
        drawn = int(np.argmax(index == k)) if k <= 5 else None
        assert int(given[0]) == k
        if drawn is not None:
            np.testing.assert_allclose(np.asarray(given[1]), start[drawn], atol=1e-6)
            np.testing.assert_allclose(float(given[2]), yaw[drawn], atol=1e-6)
        else:  # beyond max_index: only the explicit form reaches it
            np.testing.assert_allclose(np.asarray(given[1]), np.asarray(checkpoints)[k - 1], atol=1e-6)


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"goal__track_starts": 3}, "needs goal.mode 'spiral'"),
        ({"goal__mode": "spiral", "goal__num_checkpoints": 8, "goal__track_starts": 8}, "0..7"),
        ({"goal__mode": "spiral", "goal__track_starts": -1}, "0..7"),
    ],
)
def test_bad_track_starts_are_refused(overrides, match):
    with pytest.raises(ValueError, match=match):
        hsa_mjx.config.validate(hsa_mjx.config.with_overrides(hsa_mjx.config.EnvConfig(), **overrides))


def test_evaluation_starts_spiral_episodes_at_the_origin():
    trained = hsa_mjx.config.with_overrides(
        hsa_mjx.config.get_preset("spiral"), goal__num_checkpoints=20, goal__track_starts=19
    )
    evaluated = evaluation_env_config(trained)
    assert evaluated.goal.track_starts == 0
    assert evaluated.goal.num_checkpoints == 20 and evaluated.terrain == trained.terrain

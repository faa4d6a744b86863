"""The height scan (terrain heights around the robot, turned with its heading) and the privileged critic:
hand-made grounds read at the expected points, the config's checks, and a policy that never sees the
critic's inputs. The scan inside the env on the JAX and C physics paths is checked in test_host_physics."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx.config
from hsa_mjx.task import observation, privileged
from hsa_mjx.terrain import height_scan
from hsa_mjx.terrain.height_scan import HeightScanConfig
from train import config as train_config
from train.learners.ppo.networks import init_training_state, make_networks
from train.learners.ppo.policy import policy_arrays

DEFAULT = HeightScanConfig(enabled=True)
POSITION = np.array([1.0, 2.0], np.float32)
REST = 0.14
HEADINGS = {0: np.array([1.0, 0.0], np.float32), 90: np.array([0.0, 1.0], np.float32)}


def step_ground(xy: jax.Array) -> jax.Array:
    """A 0.1 m step up where world x > 1.3 (0.3 m ahead of the robot at heading 0)."""
    return jnp.where(xy[..., 0] > 1.3, 0.1, 0.0)


def slope_ground(xy: jax.Array) -> jax.Array:
    """A 0.2 rise per metre along world x."""
    return 0.2 * xy[..., 0]


def _scan(ground, heading: int, robot_z: float = REST) -> np.ndarray:
    """The default scan (unclipped metres) of a robot at ``POSITION`` facing ``heading`` degrees, (P,)."""
    points = jnp.asarray(height_scan.local_points(DEFAULT))
    return np.asarray(
        height_scan.read(
            ground, points, jnp.asarray(POSITION), jnp.asarray(HEADINGS[heading]), jnp.asarray(robot_z), REST
        )
    )


def test_default_grid_is_63_points_symmetric_about_the_robot_at_the_terrain_spacing():
    points = height_scan.local_points(DEFAULT)
    assert points.shape == (63, 2) and height_scan.num_points(DEFAULT) == 63
    np.testing.assert_allclose(points.min(axis=0), [-0.8, -0.6], atol=1e-6)
    np.testing.assert_allclose(points.max(axis=0), [0.8, 0.6], atol=1e-6)
    np.testing.assert_allclose(np.diff(np.unique(points[:, 0])), 0.2, atol=1e-6)
    assert points[1, 0] > points[0, 0] and points[1, 1] == points[0, 1]  # x (ahead) varies fastest
    labels = height_scan.labels(DEFAULT)
    assert len(set(labels)) == 63 and labels[0] == "height_scan_x-80_y-60" and labels[-1] == "height_scan_x+80_y+60"
    assert height_scan.num_points(HeightScanConfig()) == 0 and height_scan.labels(HeightScanConfig()) == ()


@pytest.mark.parametrize("heading", [0, 90])
def test_a_step_reads_its_height_ahead_of_the_robot_and_zero_elsewhere(heading):
    points = height_scan.local_points(DEFAULT)
    ahead = points[:, 0] if heading == 0 else -points[:, 1]  # how far along world +x each point lies
    expected = np.where(ahead > 0.3 + 1e-6, 0.1, 0.0)
    np.testing.assert_allclose(_scan(step_ground, heading), expected, atol=1e-6)
    assert 0 < expected.sum() < 0.1 * len(expected)  # some points on each side of the step


@pytest.mark.parametrize("heading", [0, 90])
def test_a_slope_reads_the_rise_at_each_turned_point_relative_to_the_robot(heading):
    points = height_scan.local_points(DEFAULT)
    if heading == 0:  # local x ahead is world +x
        world_x = POSITION[0] + points[:, 0]
    else:  # facing world +y: local y (left) points to world -x
        world_x = POSITION[0] - points[:, 1]
    np.testing.assert_allclose(_scan(slope_ground, heading), 0.2 * world_x, atol=1e-6)
    lifted = _scan(slope_ground, heading, robot_z=REST + 0.05)
    np.testing.assert_allclose(lifted, 0.2 * world_x - 0.05, atol=1e-6)  # relative to the robot's height


def test_shape_clips_then_scales_and_noise_is_bounded_per_point():
    config = HeightScanConfig(enabled=True, clip=0.3, scale=2.0, noise=0.05)
    heights = jnp.array([-1.0, -0.1, 0.0, 0.2, 0.9])
    np.testing.assert_allclose(height_scan.shape(heights, config), [-0.6, -0.2, 0.0, 0.4, 0.6], atol=1e-6)
    zeros = jnp.zeros(500)
    noisy = np.asarray(height_scan.add_noise(zeros, jax.random.PRNGKey(0), config))
    assert np.abs(noisy).max() <= 0.05 and noisy.std() > 0.02
    other = np.asarray(height_scan.add_noise(zeros, jax.random.PRNGKey(1), config))
    assert not np.allclose(noisy, other)
    exact = HeightScanConfig(enabled=True)
    assert height_scan.add_noise(zeros, jax.random.PRNGKey(0), exact) is zeros


@pytest.mark.parametrize(
    "key,value,needle",
    [
        ("spacing", 0.0, "spacing"),
        ("noise", -0.1, "noise"),
        ("clip", -1.0, "clip"),
        ("length", -1.0, "length"),
        ("spacing", 0.001, "points"),
    ],
)
def test_bad_scan_settings_are_refused_naming_the_key(key, value, needle):
    with pytest.raises(ValueError, match=needle):
        hsa_mjx.config.with_overrides(
            hsa_mjx.config.get_preset("mixed"),
            **{"observation.height_scan.enabled": True, f"observation.height_scan.{key}": value},
        )
    with pytest.raises(ValueError, match="unknown config key"):
        hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset("mixed"), **{"observation.height_scan.radius": 1.0})


def test_the_scan_is_appended_to_the_observation_and_labelled():
    config = hsa_mjx.config.ObservationConfig(heading=True, height_scan=DEFAULT)
    labels = observation.observation_labels(config)
    assert observation.observation_size(config) == 28 + 63 and labels[28] == "height_scan_x-80_y-60"
    names = privileged.labels(config)
    assert privileged.size(config) == len(names) == 63 + 12 + 4 + 11 + 1
    assert names[0] == "clean_height_scan_x-80_y-60" and names[-1] == "terrain_level"


def _privileged_config() -> train_config.TrainConfig:
    return train_config.from_dict(
        {
            "env": {
                "preset": "mixed",
                "goal": {"mode": "radial"},
                "observation": {"heading": True, "height_scan": {"enabled": True}},
            },
            "ppo": {"privileged_critic": True, "policy_hidden_sizes": [16, 16], "value_hidden_sizes": [16, 16]},
        }
    )


def test_privileged_inputs_reach_the_critic_and_never_the_policy_or_its_export():
    config = _privileged_config()
    n_obs, n_priv = observation.observation_size(config.env.observation), privileged.size(config.env.observation)
    networks = make_networks(config, n_obs, 8, n_priv)
    ts = init_training_state(config, networks, jax.random.PRNGKey(0), n_obs + n_priv)
    rng = np.random.default_rng(0)
    obs = jnp.asarray(rng.normal(size=(4, n_obs)), jnp.float32)
    a, b = (jnp.asarray(rng.normal(size=(4, n_priv)), jnp.float32) for _ in range(2))

    def policy(x):
        return networks.policy_network.apply(ts.normalizer, ts.params.policy, x)

    def value(x):
        return networks.value_network.apply(ts.normalizer, ts.params.value, x)

    with_a, with_b = policy(jnp.concatenate([obs, a], -1)), policy(jnp.concatenate([obs, b], -1))
    np.testing.assert_array_equal(with_a, with_b)  # the privileged values change nothing for the policy
    np.testing.assert_allclose(policy(obs), with_a, atol=1e-6)  # and it runs on its own observation alone
    assert not np.allclose(value(jnp.concatenate([obs, a], -1)), value(jnp.concatenate([obs, b], -1)))
    params = policy_arrays(config, ts, 8)
    assert params["kernels"][0].shape[0] == params["obs_mean"].shape[0] == n_obs  # the export: actor inputs only

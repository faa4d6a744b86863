"""The Gymnasium adapter: registration, check_env, determinism, bad input, rendering."""

import ctypes.util

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import hsa_mjx  # noqa: F401  (registers hsa_mjx/HSA-v0)


@pytest.fixture(scope="module")
def gym_env():
    env = gymnasium.make("hsa_mjx/HSA-v0", render_mode="rgb_array", width=96, height=72)
    yield env
    env.close()


def test_passes_check_env(gym_env):
    check_env(gym_env.unwrapped)  # includes the render check of every render mode


def test_spaces_and_step_types(gym_env):
    assert gym_env.observation_space.shape == (24,) and gym_env.action_space.shape == (8,)
    obs, info = gym_env.reset(seed=0)
    assert obs.dtype == np.float32 and obs in gym_env.observation_space
    obs, reward, terminated, truncated, info = gym_env.step(gym_env.action_space.sample())
    assert obs.dtype == np.float32 and isinstance(reward, float)
    assert isinstance(terminated, bool) and isinstance(truncated, bool)
    assert "reward/forward" in info and isinstance(info["termination_reasons"], list)


def test_observation_space_follows_the_heading_option(gym_env):
    assert gym_env.observation_space.shape == (gym_env.unwrapped.env.observation_size,) == (24,)
    heading = gymnasium.make("hsa_mjx/HSA-v0", observation__heading=True)  # built, not compiled
    assert heading.observation_space.shape == (heading.unwrapped.env.observation_size,) == (28,)
    heading.close()


def test_thousand_random_steps(gym_env):
    """1000 random steps (resetting after each episode end) stay finite and inside the spaces."""
    obs, _ = gym_env.reset(seed=11)
    gym_env.action_space.seed(11)
    ends = 0
    for _ in range(1000):
        obs, reward, terminated, truncated, info = gym_env.step(gym_env.action_space.sample())
        assert np.all(np.isfinite(obs)) and np.isfinite(reward)
        if terminated or truncated:
            ends += 1
            obs, _ = gym_env.reset()
    assert obs in gym_env.observation_space
    assert ends < 1000  # episodes last (the flat preset truncates at 4000 steps)


def test_same_seed_same_trajectory(gym_env):
    def rollout(seed):
        obs, _ = gym_env.reset(seed=seed)
        rng = np.random.default_rng(0)
        out = [obs]
        for _ in range(20):
            out.append(gym_env.step(rng.uniform(-1, 1, 8).astype(np.float32))[0])
        return np.stack(out)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3)[0], rollout(4)[0])  # a different goal


def test_bad_actions_raise_clear_errors(gym_env):
    gym_env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(8,\)"):
        gym_env.step(np.zeros(7, np.float32))
    with pytest.raises(ValueError, match="dtype int64"):
        gym_env.step(np.zeros(8, np.int64))
    with pytest.raises(ValueError, match="non-finite"):
        gym_env.step(np.full(8, np.nan, np.float32))


def test_reset_options(gym_env):
    obs, info = gym_env.reset(seed=0, options={"goal": (2.0, 0.0)})
    assert obs[21] == pytest.approx(2.0, abs=1e-4) and np.allclose(info["goal"], [2.0, 0.0])
    with pytest.raises(ValueError, match="valid options"):
        gym_env.reset(options={"terrain": "lava"})


def test_rgb_array_render_shows_the_robot(gym_env):
    gym_env.reset(seed=0)
    frame = gym_env.render()
    assert frame.shape == (72, 96, 3) and frame.dtype == np.uint8
    assert frame.std() > 5  # not a blank image


def test_bad_render_mode_and_preset():
    with pytest.raises(ValueError, match="render_mode"):
        gymnasium.make("hsa_mjx/HSA-v0", render_mode="vr")
    with pytest.raises(ValueError, match="available presets"):
        gymnasium.make("hsa_mjx/HSA-v0", config="nope")


def test_make_max_episode_steps_is_the_envs_own_limit():
    longer = gymnasium.make("hsa_mjx/HSA-v0", max_episode_steps=5000)  # built, not compiled
    assert longer.unwrapped.env.config.termination.max_episode_steps == 5000 == longer.spec.max_episode_steps
    assert gymnasium.make("hsa_mjx/HSA-v0").unwrapped.env.config.termination.max_episode_steps == 4000
    spiral = gymnasium.make("hsa_mjx/HSA-v0", config="spiral", max_episode_steps=-1)  # no TimeLimit: the preset's
    assert spiral.unwrapped.env.config.termination.max_episode_steps == 8000
    with pytest.raises(ValueError, match="max_episode_steps=50 and termination__max_episode_steps=60"):
        gymnasium.make("hsa_mjx/HSA-v0", max_episode_steps=50, termination__max_episode_steps=60)


def test_gl_platform_is_chosen_for_a_headless_machine_and_a_users_choice_kept():
    from hsa_mjx.sim import gl

    assert gl.choose_platform({"MUJOCO_GL": "osmesa"}) == "osmesa"
    assert gl.choose_platform({"DISPLAY": ":0"}) is None  # MuJoCo's default (GLFW) with a display
    headless: dict = {}
    expected = next((p for p, lib in gl.OFFSCREEN if ctypes.util.find_library(lib)), None)
    assert gl.choose_platform(headless) == expected and headless.get("MUJOCO_GL") == expected
    assert expected == "egl"  # this machine (and CI's) has EGL


def test_render_works_headless_with_mujoco_gl_unset(tmp_path):
    """The README's render snippet in a fresh process without MUJOCO_GL or a display."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    code = (
        "import gymnasium, os, hsa_mjx\n"
        "env = gymnasium.make('hsa_mjx/HSA-v0', render_mode='rgb_array', width=64, height=48)\n"
        "env.reset(seed=0)\n"
        "frame = env.render()\n"
        "print(os.environ['MUJOCO_GL'], frame.shape, frame.dtype, int(frame.std() > 1))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("\n")[-2] == "egl (48, 64, 3) uint8 1", out.stdout


def test_packed_state_round_trips_and_refuses_another_layout():
    """One buffer per dtype and back, inside jit and on the host; a leaf of another shape is refused."""
    import jax
    import jax.numpy as jnp

    from hsa_mjx.adapters.packed import Packing, to_host

    tree = {"a": jnp.arange(6.0).reshape(2, 3), "b": (jnp.int32(4), jnp.array([True, False])), "c": jnp.ones(())}
    layout = Packing(jax.eval_shape(lambda: tree))
    assert [str(d) for d in layout.dtypes] == ["bool", "float32", "int32"] and layout.sizes == (2, 7, 1)
    back = jax.jit(lambda t: layout.unpack(layout.pack(t)))(tree)
    host = layout.unpack(layout.pack(jax.device_get(tree), np))
    fetched = layout.unpack(to_host(jax.jit(layout.pack)(tree)))  # the host copy of jitted buffers
    assert all(isinstance(leaf, np.ndarray) for leaf in jax.tree.leaves(fetched))
    for got in (back, host, fetched):
        assert jax.tree.all(jax.tree.map(lambda x, y: np.array_equal(x, y) and x.dtype == y.dtype, got, tree))
    scalars = layout.unpack_host(to_host(jax.jit(layout.pack)(tree)))  # 0-d leaves as Python scalars
    assert scalars["b"][0] == 4 and type(scalars["b"][0]) is int and type(scalars["c"]) is float
    np.testing.assert_array_equal(scalars["a"], tree["a"])
    with pytest.raises(ValueError, match="shape"):
        layout.pack({**tree, "a": jnp.zeros(3)})


def test_c_physics_step_is_the_envs_own_step(gym_env):
    """The Gymnasium env's C MuJoCo step (two jitted halves around the host's substeps) plays exactly the
    env's ``step`` (its substeps through a callback) from the same state."""
    import jax

    env = gym_env.unwrapped
    assert env.env.physics_backend == "c"
    gym_env.reset(seed=5)
    state, step = env.state, jax.jit(env.env.step)
    rng = np.random.default_rng(1)
    for _ in range(4):
        action = rng.uniform(-1, 1, 8).astype(np.float32)
        obs, reward, *_ = gym_env.step(action)
        state = step(state, action)
        np.testing.assert_array_equal(obs, np.asarray(state.obs))
        assert reward == float(state.reward)
    np.testing.assert_array_equal(
        np.asarray(env.state.pipeline_state.physics.qpos), np.asarray(state.pipeline_state.physics.qpos)
    )

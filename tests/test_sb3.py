"""The Stable-Baselines3 VecEnv adapter: SB3's step contract, and SB3's PPO training on it."""

import numpy as np
import pytest

from hsa_mjx.adapters.sb3 import SB3VecEnv  # the sb3 extra, part of the test extra

EPISODE, ENVS = 5, 8


@pytest.fixture(scope="module")
def envs():
    import jax
    from conftest import OPTIMISED

    venv = SB3VecEnv(ENVS, termination__max_episode_steps=EPISODE)
    batched = venv.venv.unwrapped  # PPO runs this step 256 times: compiled at O3, as conftest's hot batch step
    batched._step_fn = jax.jit(batched._step_outputs, compiler_options=OPTIMISED)
    yield venv
    venv.close()


def test_step_contract_terminal_observation_and_episode_info(envs):
    envs.seed(3)
    obs = envs.reset()
    assert obs.shape == (ENVS, 24) and obs.dtype == np.float32 and obs.flags.writeable
    again = (envs.seed(3), envs.reset())[1]
    np.testing.assert_array_equal(obs, again)  # seeded resets repeat
    for step in range(1, EPISODE + 1):
        obs, rewards, dones, infos = envs.step(np.zeros((ENVS, 8), np.float32))
        assert obs.flags.writeable and rewards.dtype == np.float32 and len(infos) == ENVS
        assert dones.all() == (step == EPISODE)
    for info in infos:  # every env ended by the time limit on this step
        assert info["TimeLimit.truncated"] and info["episode"]["l"] == EPISODE
        assert info["terminal_observation"].shape == (24,)
    np.testing.assert_array_equal(obs[:, 16:18], again[:, 16:18])  # the returned obs are the new episodes' starts
    assert envs.get_attr("render_mode") == [None] * ENVS and envs.env_is_wrapped(object) == [False] * ENVS


def test_sb3_ppo_trains_2048_steps_on_the_adapter(envs, tmp_path):
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure

    model = PPO("MlpPolicy", envs, n_steps=256, batch_size=256, n_epochs=1, seed=0, device="cpu")
    model.set_logger(configure(str(tmp_path), []))  # SB3's default logger leaves an empty folder in /tmp
    model.learn(total_timesteps=2048)
    assert model.num_timesteps == 2048
    assert len(model.ep_info_buffer) > 0 and all(e["l"] == EPISODE for e in model.ep_info_buffer)
    action, _ = model.predict(envs.reset(), deterministic=True)
    assert action.shape == (ENVS, 8) and np.all(np.isfinite(action))

"""The Gymnasium vector env: make_vec, the vector API checks, same-step autoreset, seeds, bad input, render."""

import os

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import VECTOR_ENVS, VECTOR_EPISODE_STEPS
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from hsa_mjx.adapters.gymnasium import episode_key
from hsa_mjx.adapters.gymnasium_vector import HSAVectorEnv, NumpyOutput
from hsa_mjx.task.termination import REASONS

ACTION_SHAPE = (VECTOR_ENVS, 8)


def _actions(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, ACTION_SHAPE).astype(np.float32)


def _check_info(info: dict, num_envs: int) -> None:
    """Gymnasium's vector info layout: every key an array over envs with a boolean ``_key`` mask."""
    for key, value in info.items():
        if key.startswith("_"):
            assert key[1:] in info and value.dtype == np.bool_ and value.shape == (num_envs,), key
        elif isinstance(value, dict):
            _check_info(value, num_envs)
            assert f"_{key}" in info
        else:
            assert value.shape[0] == num_envs and f"_{key}" in info, key


def test_make_vec_gives_the_device_batched_env(vector_env):
    assert isinstance(vector_env, NumpyOutput) and isinstance(vector_env.unwrapped, HSAVectorEnv)
    assert vector_env.num_envs == VECTOR_ENVS
    assert vector_env.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert vector_env.single_action_space.shape == (8,)
    assert vector_env.observation_space == batch_space(vector_env.single_observation_space, VECTOR_ENVS)
    assert vector_env.action_space == batch_space(vector_env.single_action_space, VECTOR_ENVS)


def test_vector_api_checks(vector_env):
    """The checks Gymnasium's own vector tests make: types, shapes, spaces, info layout, determinism."""
    obs, info = vector_env.reset(seed=3)
    assert isinstance(obs, np.ndarray) and obs.dtype == np.float32 and obs in vector_env.observation_space
    _check_info(info, VECTOR_ENVS)
    obs2, info2 = vector_env.reset(seed=3)
    assert data_equivalence((obs, info), (obs2, info2))
    first = vector_env.step(_actions(0))
    obs, reward, terminated, truncated, info = first
    assert obs.dtype == np.float32 and obs in vector_env.observation_space
    assert reward.dtype == np.float32 and reward.shape == (VECTOR_ENVS,)
    assert terminated.dtype == np.bool_ and truncated.dtype == np.bool_ and terminated.shape == (VECTOR_ENVS,)
    _check_info(info, VECTOR_ENVS)
    assert {"reward/forward", "is_success", "distance_to_goal", "final_obs", "final_info"} <= set(info)
    assert {f"termination/{r}" for r in REASONS} <= set(info)
    vector_env.reset(seed=3)
    assert data_equivalence(first, vector_env.step(_actions(0)))  # same seed and actions, same step
    assert not np.array_equal(vector_env.reset(seed=4)[0], vector_env.reset(seed=3)[0])  # other goals


def test_same_step_autoreset_returns_the_next_episode(vector_env):
    """An ending step returns the new episode's first obs (new goal); the terminal one is in final_obs."""
    obs, info = vector_env.reset(seed=5)
    goals = info["goal"].copy()
    for step in range(1, VECTOR_EPISODE_STEPS + 1):
        obs, reward, terminated, truncated, info = vector_env.step(_actions(step))
        if step < VECTOR_EPISODE_STEPS:
            assert not info["_final_obs"].any()
    done = terminated | truncated
    assert done.all() and truncated.all() and not terminated.any()  # the episode limit, no failure
    assert np.array_equal(info["_final_obs"], done) and np.array_equal(info["_final_info"], done)
    assert np.all(obs[:, :16] == 0) and np.all(np.abs(info["final_obs"][:, :16]).sum(axis=1) > 0)  # at rest again
    final = info["final_info"]
    assert np.all(final["episode_length"] == VECTOR_EPISODE_STEPS) and np.all(final["_episode_length"])
    assert np.all(info["reward/forward"] == 0) and np.any(final["reward/forward"] != 0)  # reset info on top
    assert np.allclose(final["goal"], goals) and not np.allclose(info["goal"], goals)  # goals redrawn
    assert np.allclose(info["distance_to_goal"], np.linalg.norm(info["goal"] - obs[:, 16:18], axis=1), atol=1e-5)
    _, _, terminated, truncated, info = vector_env.step(_actions(0))
    assert not (terminated | truncated).any() and not info["_final_obs"].any()


def test_env_i_is_the_single_env_seeded_with_seed_plus_i(vector_env, jit_single):
    reset, _, _ = jit_single
    obs, _ = vector_env.reset(seed=40)
    for i in (0, VECTOR_ENVS - 1):
        np.testing.assert_allclose(obs[i], np.asarray(reset(episode_key(40 + i)).obs), atol=1e-6)
    listed, _ = vector_env.reset(seed=[40 + i for i in range(VECTOR_ENVS)])
    np.testing.assert_array_equal(listed, obs)
    vector_env.reset(seed=40)
    seedless = [vector_env.reset()[0] for _ in range(2)]  # seeds drawn from the seeded np_random
    assert not np.array_equal(seedless[0], seedless[1])
    vector_env.reset(seed=40)
    np.testing.assert_array_equal(vector_env.reset()[0], seedless[0])  # reproducible
    for bad in ([1, 2], -1, 2**32, "7"):
        with pytest.raises(ValueError, match="seed"):
            vector_env.reset(seed=bad)


def test_bad_actions_raise_and_leave_the_env_usable(vector_env):
    vector_env.reset(seed=9)
    reference = vector_env.step(_actions(1))
    vector_env.reset(seed=9)
    nan_actions = _actions(1)
    nan_actions[2, 3] = np.nan
    for bad, match in (
        (np.zeros((VECTOR_ENVS, 7), np.float32), r"shape \(8, 8\).*got shape \(8, 7\)"),
        (np.zeros(8, np.float32), r"got shape \(8,\)"),
        (np.zeros(ACTION_SHAPE, np.int64), r"shape \(8, 8\).*dtype int64"),
        (nan_actions, r"non-finite values at indices \[\[2, 3\]\]"),
        ([[0.0] * 8] * 3 + [[0.0] * 7], "float array of shape"),
    ):
        with pytest.raises(ValueError, match=match):
            vector_env.step(bad)
    assert data_equivalence(vector_env.step(_actions(1)), reference)  # nothing advanced before
    with pytest.raises(ValueError, match="options"):
        vector_env.reset(options={"goal": (1.0, 0.0)})


def test_jax_outputs_and_device_actions(vector_env):
    """The unwrapped env speaks JAX (a torch learner wraps it in JaxToTorch: DLPack, no host copy)."""
    env = vector_env.unwrapped
    obs, info = env.reset(seed=1)
    assert isinstance(obs, jax.Array) and obs.dtype == jnp.float32 and isinstance(info["goal"], jax.Array)
    obs, reward, terminated, truncated, info = env.step(jnp.asarray(_actions(2)))
    assert all(isinstance(x, jax.Array) for x in (obs, reward, terminated, truncated, info["final_obs"]))
    env.step(jax.device_put(_actions(3), jax.devices()[0]))  # committed to a device (as DLPack imports are)
    vector_env.step(_actions(4))  # numpy
    assert env._step_fn._cache_size() == 1  # one compiled step whatever the kind of actions
    with pytest.raises(ValueError, match="non-finite"):
        env.step(jnp.full(ACTION_SHAPE, jnp.nan))
    with pytest.raises(ValueError, match="dtype int32"):
        env.step(jnp.zeros(ACTION_SHAPE, jnp.int32))


def test_render_draws_the_chosen_env(vector_env):
    vector_env.reset(seed=2)
    for step in range(3):
        vector_env.step(_actions(10 + step))
    env = vector_env.unwrapped
    env.render_env = 0
    first = vector_env.render()
    env.render_env = 5
    other = vector_env.render()
    assert first.shape == (72, 96, 3) and first.dtype == np.uint8 and first.std() > 5
    assert not np.array_equal(first, other)  # another robot, another goal
    env.render_env = VECTOR_ENVS
    with pytest.raises(ValueError, match="render_env"):
        vector_env.render()
    env.render_env = 0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_envs": 0}, "num_envs must be an integer >= 1"),
        ({"num_envs": 2, "output": "torch"}, "output must be one of"),
        ({"num_envs": 2, "render_env": 2}, "render_env"),
        ({"num_envs": 2, "render_mode": "vr"}, "render_mode"),
    ],
)
def test_bad_constructor_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):  # raised before anything is built or compiled
        gymnasium.make_vec("hsa_mjx/HSA-v0", vectorization_mode="vector_entry_point", **kwargs)


def test_next_step_autoreset_suits_gymnasiums_vector_wrappers():
    """autoreset_mode="next_step": the ending step shows the terminal state, the next one the new
    episode's first observation with reward 0 and no flags (its action ignored); Gymnasium's
    NormalizeObservation, which refuses same-step autoreset, wraps it."""
    from gymnasium.wrappers.vector import NormalizeObservation

    envs = gymnasium.make_vec(
        "hsa_mjx/HSA-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        autoreset_mode="next_step",
        termination__max_episode_steps=3,
    )
    assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    norm = NormalizeObservation(envs)
    obs, _ = norm.reset(seed=0)
    first, _ = envs.reset(seed=0)
    flags, rewards, observations = [], [], [first]
    for i in range(8):
        obs, reward, terminated, truncated, info = envs.step(_actions(i)[:2])
        flags.append(bool(truncated[0])), rewards.append(reward), observations.append(obs)
        assert not terminated.any() and "final_obs" not in info
    assert flags == [False, False, True, False, False, False, True, False]  # 3 steps, a reset step, 3 steps
    assert np.all(rewards[3] == 0.0) and np.all(rewards[2] != 0.0)
    np.testing.assert_array_equal(observations[4][:, 16:18], first[:, 16:18])  # back at the start position (robot xy)
    assert not np.allclose(observations[3][:, 16:18], first[:, 16:18])  # the terminal step is not the start
    assert np.all(np.isfinite(norm.step(_actions(9)[:2])[0]))
    with pytest.raises(ValueError, match=r"autoreset_mode 'disabled'.*same_step.*next_step"):
        HSAVectorEnv(2, autoreset_mode="disabled")


def test_async_vectorization_with_spawned_workers(tmp_path):
    """make_vec(..., vectorization_mode="async") as a user's script runs it (its own process, the main guard),
    with the spawn context the docs give: importing hsa_mjx leaves the start method alone (one spawned
    worker: each one imports JAX and MuJoCo and builds its env)."""
    import subprocess
    import sys

    script = tmp_path / "run_async.py"
    script.write_text(
        "import multiprocessing, gymnasium, numpy as np, hsa_mjx\n"
        "from hsa_mjx.adapters.entry_points import SPAWN\n"
        "if __name__ == '__main__':\n"
        "    method = multiprocessing.get_start_method(allow_none=True)  # after import hsa_mjx: the program's own\n"
        "    envs = gymnasium.make_vec('hsa_mjx/HSA-v0', num_envs=1, vectorization_mode='async', vector_kwargs=SPAWN)\n"
        "    obs, _ = envs.reset(seed=0)\n"
        "    obs, reward, *_ = envs.step(np.zeros((1, 8), np.float32))\n"
        "    print(method, obs.shape, np.isfinite(reward).all())\n"
        "    envs.close()\n"
    )
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "None (1, 24) True"  # no start method set by the import


def test_an_env_in_a_forked_copy_of_a_jax_process_is_refused(monkeypatch):
    """Forked workers of a process that built an env would deadlock: the entry point says to spawn them."""
    from hsa_mjx.adapters import entry_points

    monkeypatch.setattr(entry_points, "_built_in", [os.getpid() + 1])  # as a forked copy sees its parent's record
    with pytest.raises(RuntimeError, match=r"forked.*vector_kwargs=\{'context': 'spawn'\}"):
        entry_points.single_env()
    monkeypatch.setattr(entry_points, "_built_in", [os.getpid()])
    entry_points.check_not_forked()  # the process that built the env: fine

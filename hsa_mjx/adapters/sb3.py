"""The device-batched env as a Stable-Baselines3 ``VecEnv`` (``pip install "hsa_mjx[sb3]"``).

::

    from stable_baselines3 import PPO
    from hsa_mjx.adapters.sb3 import SB3VecEnv
    envs = SB3VecEnv(num_envs=64, config="flat", goal__mode="radial")   # make_vec's arguments
    PPO("MlpPolicy", envs, n_steps=256).learn(1_000_000)

All envs step in one jitted call (:class:`~hsa_mjx.adapters.gymnasium_vector.HSAVectorEnv`,
same-step autoreset, which is SB3's own contract): ``step_wait`` returns the next episode's first
observation where one ended, with the terminal one in ``infos[i]["terminal_observation"]``,
``infos[i]["TimeLimit.truncated"]`` for a time-limit end, and ``infos[i]["episode"]`` (``r``, ``l``,
``t``: what SB3's ``Monitor`` adds, so the rollout logs fill without a ``VecMonitor``). Observations
and rewards are writable numpy copies (SB3's buffers and ``VecNormalize`` modify them in place).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from hsa_mjx.adapters.gymnasium_vector import make_vector_env

INFO_KEYS = ("is_success", "distance_to_goal", "checkpoint_index")  # per-env values copied into every info


class SB3VecEnv(VecEnv):
    """``num_envs`` HSA envs on the device behind Stable-Baselines3's ``VecEnv`` API.

    Args:
        num_envs: batch size (>= 1).
        **kwargs: as ``gymnasium.make_vec("hsa_mjx/HSA-v0", ...)``: ``config``, ``render_mode``,
            config keys and the original's argument names (:func:`hsa_mjx.make_env`).
    """

    def __init__(self, num_envs: int, **kwargs: Any):
        if "autoreset_mode" in kwargs or "output" in kwargs:
            raise ValueError("SB3VecEnv sets autoreset_mode (same_step, SB3's contract) and output (numpy) itself")
        self.venv = make_vector_env(num_envs, output="numpy", **kwargs)
        self._actions: np.ndarray | None = None
        self._t0 = time.perf_counter()
        super().__init__(num_envs, self.venv.single_observation_space, self.venv.single_action_space)

    def reset(self) -> np.ndarray:
        """Reset every env (with the seed given to ``seed()``, once); the first observations."""
        seed = self._seeds[0]
        obs, info = self.venv.reset(seed=seed)
        self._seeds = [None] * self.num_envs
        self.reset_infos = self._per_env(info)
        return np.array(obs)

    def step_async(self, actions: np.ndarray) -> None:
        """Keep the actions (num_envs, 8) for ``step_wait``."""
        self._actions = np.asarray(actions, np.float32)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """One device step of every env: (obs, rewards, dones, infos) in SB3's layout."""
        obs, reward, terminated, truncated, info = self.venv.step(self._actions)
        dones = np.logical_or(terminated, truncated)
        infos = self._per_env(info)
        elapsed = round(time.perf_counter() - self._t0, 6)
        final, final_obs = info.get("final_info", {}), info.get("final_obs")
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = np.array(final_obs[i])
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            infos[i]["episode"] = {
                "r": float(final["episode_return"][i]),
                "l": int(final["episode_length"][i]),
                "t": elapsed,
            }
            for key in INFO_KEYS:  # the finished episode's, not the new one's
                infos[i][key] = _item(final[key][i])
        return np.array(obs), np.array(reward, np.float32), dones, infos

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next ``reset``: env i uses ``seed + i``."""
        self._seeds = [None if seed is None else seed + i for i in range(self.num_envs)]
        return self._seeds

    def close(self) -> None:
        """Release the env (and its renderer)."""
        self.venv.close()

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """A frame of the vector env's ``render_env`` (``render_mode="rgb_array"``)."""
        return self.venv.render()

    def get_images(self) -> Sequence[np.ndarray | None]:
        """The one frame ``render`` draws, once per env slot SB3 asks for."""
        return [self.venv.render()] * self.num_envs

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """An attribute of the batched env, once per requested env (they share one env object)."""
        return [getattr(self.venv.unwrapped, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute on the batched env (it applies to every env)."""
        setattr(self.venv.unwrapped, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices: VecEnvIndices = None, **kwargs: Any) -> list[Any]:
        """Call a method of the batched env once; its result, once per requested env."""
        result = getattr(self.venv.unwrapped, method_name)(*args, **kwargs)
        return [result] * len(self._get_indices(indices))

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """No Gymnasium wrapper sits around the batched env."""
        return [False] * len(self._get_indices(indices))

    def _per_env(self, info: dict) -> list[dict[str, Any]]:
        """Gymnasium's vector info (arrays over envs) as SB3's list of per-env dicts (a few keys)."""
        return [{key: _item(info[key][i]) for key in INFO_KEYS if key in info} for i in range(self.num_envs)]


def _item(value: Any) -> Any:
    """A numpy scalar as a Python number (bool, int or float)."""
    return value.item() if hasattr(value, "item") else value

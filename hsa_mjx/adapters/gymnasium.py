"""Gymnasium adapter: one HSA env behind the standard ``reset``/``step``/``render`` API.

Registered as ``hsa_mjx/HSA-v0`` when ``hsa_mjx`` is imported::

    env = gymnasium.make("hsa_mjx/HSA-v0")                    # the "flat" preset
    env = gymnasium.make("hsa_mjx/HSA-v0", config="configs/flat.yaml", render_mode="rgb_array")
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from gymnasium import spaces

from hsa_mjx.config import EnvConfig
from hsa_mjx.env import HSAEnv
from hsa_mjx.terrain.grid import HFIELD_NAME
from hsa_mjx.termination import REASONS
from hsa_mjx.types import EnvState


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class HSAGymEnv(gymnasium.Env):
    """A single :class:`~hsa_mjx.env.HSAEnv` as a ``gymnasium.Env`` (float32 numpy in and out).

    Args:
        config: preset name, YAML path or :class:`EnvConfig` (default ``"flat"``).
        render_mode: ``None``, ``"rgb_array"`` (offscreen ``mujoco.Renderer``) or ``"human"``
            (passive MuJoCo viewer; needs a display).
        width, height: size of ``rgb_array`` frames.
        camera: camera name in the asset (``"track"`` follows the robot, ``"overview"`` is fixed).
        **overrides: config overrides as in :func:`hsa_mjx.make_env`.

    ``step`` returns ``(obs, reward, terminated, truncated, info)``; ``info`` holds the reward
    components (``reward/<term>``), ``termination_reasons`` (list of names), ``distance_to_goal``,
    ``goal`` and ``is_success``. ``reset(options={"goal": (x, y)})`` places the goal by hand.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}

    def __init__(self, config: str | Path | EnvConfig = "flat", render_mode: str | None = None,
                 width: int = 640, height: int = 480, camera: str = "track", **overrides: Any):
        from hsa_mjx import make_env  # deferred: hsa_mjx imports this module at registration

        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode {render_mode!r} is not supported; use one of "
                             f"{[None, *self.metadata['render_modes']]}")
        self.env: HSAEnv = make_env(config, **overrides)
        self.render_mode = render_mode
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / self.env.dt)))
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.env.observation_size,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (self.env.action_size,), np.float32)
        self._reset_fn = jax.jit(self.env.reset)
        self._step_fn = jax.jit(self.env.step)
        self._goal_fn = jax.jit(self.env.set_goal)
        self._state: EnvState | None = None
        self._width, self._height, self._camera = width, height, camera
        self._renderer: mujoco.Renderer | None = None
        self._viewer = None
        self._warned_no_display = False
        self._render_data = mujoco.MjData(self.env.robot.mj_model)
        self._hfield_stale = False  # the C model's heightfield lags this env's terrain

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; the same ``seed`` gives the same episode."""
        super().reset(seed=seed)
        key = jax.random.PRNGKey(int(self.np_random.integers(0, 2**31 - 1)))
        state = self._reset_fn(key)
        options = dict(options or {})
        if "goal" in options:
            goal = np.asarray(options.pop("goal"), np.float32)
            if goal.shape != (2,) or not np.all(np.isfinite(goal)):
                raise ValueError(f"options['goal'] must be a finite (x, y) pair, got {goal!r}")
            state = self._goal_fn(state, jnp.asarray(goal))
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; valid options: ['goal']")
        self._state = state
        if self.render_mode == "human":
            self.render()
        return np.asarray(state.obs, np.float32), self._info(state)

    def step(self, action):
        """Apply one normalised action of shape (8,) in [-1, 1]."""
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        action = self._check_action(action)
        state = self._step_fn(self._state, jnp.asarray(action))
        self._state = state
        truncated = bool(state.info["truncation"] > 0)
        terminated = bool(state.done > 0) and not truncated
        if self.render_mode == "human":
            self.render()
        return (np.asarray(state.obs, np.float32), float(state.reward), terminated, truncated,
                self._info(state))

    def _check_action(self, action) -> np.ndarray:
        array = np.asarray(action)
        expected = f"a float array of shape ({self.env.action_size},) with values in [-1, 1]"
        if array.dtype.kind != "f":
            raise ValueError(f"action must be {expected}; got dtype {array.dtype}")
        if array.shape != self.action_space.shape:
            raise ValueError(f"action must be {expected}; got shape {array.shape}")
        if not np.all(np.isfinite(array)):
            raise ValueError(f"action must be {expected}; got non-finite values {array.tolist()}")
        return array.astype(np.float32)

    @staticmethod
    def _info(state: EnvState) -> dict[str, Any]:
        metrics = {k: float(v) for k, v in jax.device_get(state.metrics).items()}
        info: dict[str, Any] = {k: v for k, v in metrics.items() if k.startswith("reward/")}
        info["termination_reasons"] = [r for r in REASONS if metrics[f"termination/{r}"] > 0]
        info["is_success"] = metrics["termination/goal_reached"] > 0
        info["distance_to_goal"] = metrics["distance_to_goal"]
        info["goal"] = np.asarray(state.pipeline_state.task.goal_xy, np.float32)
        info["nonfinite_action"] = metrics["nonfinite_action"] > 0
        return info

    def _sync_render_data(self) -> mujoco.MjData:
        """Copy the MJX state into the C data used for rendering."""
        physics = jax.device_get(self._state.pipeline_state.physics)
        data = self._render_data
        data.qpos[:] = physics.qpos
        data.qvel[:] = physics.qvel
        data.mocap_pos[:] = physics.mocap_pos
        self._sync_terrain()
        mujoco.mj_forward(self.env.robot.mj_model, data)
        return data

    def _sync_terrain(self) -> None:
        """Copy this episode's own terrain (per-env terrain lives in the state) into the C model."""
        if not self.env.world.per_env:
            return
        model = self.env.robot.mj_model
        terrain = np.asarray(jax.device_get(self._state.pipeline_state.task.terrain), np.float32)
        adr = model.hfield_adr[self._hfield_id()]
        if np.array_equal(model.hfield_data[adr:adr + terrain.size], terrain):
            return
        model.hfield_data[adr:adr + terrain.size] = terrain
        self._hfield_stale = True

    def _hfield_id(self) -> int:
        """Id of the terrain heightfield in the C model."""
        return self.env.robot.mj_model.hfield(HFIELD_NAME).id

    def _upload_terrain(self) -> None:
        """Send a changed heightfield to the GPU copies held by the renderer and the viewer."""
        if not self._hfield_stale:
            return
        if self._renderer is not None:
            context = getattr(self._renderer, "_mjr_context", None)
            if context is None:  # a renderer without an accessible context: rebuild it
                self._renderer.close()
                self._renderer = None
            else:
                gl_context = getattr(self._renderer, "_gl_context", None)
                if gl_context is not None:
                    gl_context.make_current()
                mujoco.mjr_uploadHField(self.env.robot.mj_model, context, self._hfield_id())
        if self._viewer is not None:
            self._viewer.update_hfield(self._hfield_id())
        self._hfield_stale = False

    def render(self):
        """``rgb_array``: an (H, W, 3) uint8 frame; ``human``: update the viewer window."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode= to make()")
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        data = self._sync_render_data()
        if self.render_mode == "rgb_array":
            self._upload_terrain()
            if self._renderer is None:  # a new renderer uploads the current heightfield itself
                self._renderer = mujoco.Renderer(self.env.robot.mj_model, self._height, self._width)
            self._renderer.update_scene(data, camera=self._camera)
            return self._renderer.render()
        return self._render_human(data)

    def _render_human(self, data: mujoco.MjData) -> None:
        if not _has_display():
            if not self._warned_no_display:
                gymnasium.logger.warn("render_mode='human' needs a display (DISPLAY is unset): "
                                      "nothing is shown; use render_mode='rgb_array' for frames")
                self._warned_no_display = True
            return None
        if self._viewer is None:
            import mujoco.viewer
            self._viewer = mujoco.viewer.launch_passive(self.env.robot.mj_model, data)
            self._hfield_stale = False
        self._upload_terrain()
        self._viewer.sync()
        return None

    def close(self) -> None:
        """Release the renderer and viewer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

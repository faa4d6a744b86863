"""Frames of one env's state: the MJX state copied into C MuJoCo data and drawn offscreen or in a viewer.

Shared by the single Gymnasium env and the vector env (which renders one chosen env of its batch).
The C model holds the whole terrain atlas; copying the state's mocap positions places the floor so
that the env's own tile lies under the robot, as in its physics.
"""

from __future__ import annotations

import os

import gymnasium
import jax
import mujoco
import numpy as np

from hsa_mjx.sim.gl import has_display
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.task.types import EnvState

RENDER_MODES = ("human", "rgb_array")
DEFAULT_CAMERA = "track"


def check_render_mode(render_mode: str | None) -> str | None:
    """Return ``render_mode`` or raise ValueError listing the supported ones."""
    if render_mode not in (None, *RENDER_MODES):
        raise ValueError(f"render_mode {render_mode!r} is not supported; use one of {[None, *RENDER_MODES]}")
    return render_mode


def check_camera(model: mujoco.MjModel, camera: str | int | None) -> str | int:
    """A camera of ``model`` by name or id (-1: MuJoCo's free camera); None means ``"track"``."""
    names = [model.camera(i).name for i in range(model.ncam)]
    if camera is None:
        return DEFAULT_CAMERA
    if isinstance(camera, str) and camera in names:
        return camera
    if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool) and -1 <= camera < model.ncam:
        return int(camera)
    raise ValueError(
        f"unknown camera {camera!r}; cameras of the robot asset: {names} "
        f"(or an id in -1..{model.ncam - 1}, -1 being MuJoCo's free camera)"
    )


class StateRenderer:
    """Draws a single env's :class:`EnvState` with C MuJoCo.

    Args:
        env: the env whose model is drawn.
        render_mode: ``"rgb_array"`` (offscreen ``mujoco.Renderer``) or ``"human"`` (passive viewer;
            needs a display, else a one-time warning and nothing is shown).
        width, height: size of ``rgb_array`` frames.
        camera: camera name or id in the asset (None: ``"track"``, which follows the robot).
    """

    def __init__(self, env: HSAEnv, render_mode: str, width: int, height: int, camera: str | int | None):
        self.env, self.render_mode = env, check_render_mode(render_mode)
        self.camera = check_camera(env.robot.mj_model, camera)
        self._width, self._height = width, height
        self._renderer: mujoco.Renderer | None = None
        self._viewer = None
        self._warned_no_display = False
        self._gl_error: str | None = None  # a failed GL context is not retried (a retry can crash the process)
        self._data = mujoco.MjData(env.robot.mj_model)

    def render(self, state: EnvState) -> np.ndarray | None:
        """``rgb_array``: an (H, W, 3) uint8 frame; ``human``: update the viewer window (None)."""
        data = self._sync(state)
        if self.render_mode == "rgb_array":
            if self._renderer is None:
                self._renderer = self._offscreen()
            self._renderer.update_scene(data, camera=self.camera)
            return self._renderer.render()
        return self._render_human(data)

    def _offscreen(self) -> mujoco.Renderer:
        """The offscreen renderer, or a RuntimeError saying how to get one (raised again without retrying)."""
        if self._gl_error is None:
            try:
                return mujoco.Renderer(self.env.robot.mj_model, self._height, self._width)
            except Exception as err:  # mujoco.FatalError and friends: no usable OpenGL platform
                self._gl_error = (
                    f"no OpenGL context for offscreen frames ({type(err).__name__}: {err}); MUJOCO_GL is "
                    f"{os.environ.get('MUJOCO_GL')!r}. On a machine without a display set MUJOCO_GL=egl "
                    "(or osmesa) before mujoco is first imported; import hsa_mjx does so when EGL or "
                    "OSMesa is installed and mujoco was not imported before it"
                )
        raise RuntimeError(self._gl_error)

    def _sync(self, state: EnvState) -> mujoco.MjData:
        """Copy the MJX state (its terrain tile through the floor's mocap body) into the C data used for drawing."""
        physics = jax.device_get(state.pipeline_state.physics)
        data = self._data
        data.qpos[:] = physics.qpos
        data.qvel[:] = physics.qvel
        data.mocap_pos[:] = physics.mocap_pos
        mujoco.mj_forward(self.env.robot.mj_model, data)
        return data

    def _render_human(self, data: mujoco.MjData) -> None:
        if not has_display():
            if not self._warned_no_display:
                gymnasium.logger.warn(
                    "render_mode='human' needs a display (DISPLAY is unset): "
                    "nothing is shown; use render_mode='rgb_array' for frames"
                )
                self._warned_no_display = True
            return None
        if self._viewer is None:
            import mujoco.viewer

            self._viewer = mujoco.viewer.launch_passive(self.env.robot.mj_model, data)
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

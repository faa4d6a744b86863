"""Gymnasium adapter: one HSA env behind the standard ``reset``/``step``/``render`` API.

Registered as ``hsa_mjx/HSA-v0`` when ``hsa_mjx`` is imported::

    env = gymnasium.make("hsa_mjx/HSA-v0")                    # the "flat" preset
    env = gymnasium.make("hsa_mjx/HSA-v0", config="configs/flat.yaml", render_mode="rgb_array")
    env = gymnasium.make("hsa_mjx/HSA-v0", frame_skip=20, enable_terrain=True, terrain_type="craters")

The batched counterpart is ``hsa_mjx.adapters.gymnasium_vector`` (``gymnasium.make_vec``).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces

from hsa_mjx.adapters.checks import check_actions
from hsa_mjx.adapters.packed import Packing, to_host
from hsa_mjx.adapters.rendering import RENDER_MODES, StateRenderer, check_camera, check_render_mode
from hsa_mjx.config import EnvConfig
from hsa_mjx.sim.backend import one_env_config
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.task.termination import REASONS
from hsa_mjx.task.types import EnvState


def episode_key(seed: int) -> jax.Array:
    """The PRNG key of the episode that ``reset(seed=seed)`` starts (shared by the vector env)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**32:
        raise ValueError(f"seed must be an integer in [0, 2**32), got {seed!r}")
    return jax.random.PRNGKey(int(seed))


def pick_camera(camera: str | int | None, overrides: dict[str, Any]) -> str | int | None:
    """``camera``, or the original's ``camera_name`` / ``camera_id`` popped from ``overrides`` (one of them)."""
    given = {}
    for name in ("camera_name", "camera_id"):
        value = overrides.pop(name, None)
        if value is not None:  # None was the original's default: no camera chosen
            given[name] = value
    if camera is not None:
        given["camera"] = camera
    if len(given) > 1:
        raise ValueError(
            f"pass one camera argument, got {sorted(given)} (camera_name and camera_id are the "
            "original's names for camera)"
        )
    return next(iter(given.values()), None)


def _outputs(state: EnvState) -> dict[str, Any]:
    """What a Gymnasium step returns from a state (fetched from the device in one call)."""
    return {
        "obs": state.obs,
        "reward": state.reward,
        "done": state.done,
        "truncation": state.info["truncation"],
        "metrics": state.metrics,
        "goal": state.pipeline_state.task.goal_xy,
    }


def time_limit_of_make() -> int | None:
    """The ``max_episode_steps`` that a ``gymnasium.make`` now creating an env was given (None: none).

    Gymnasium keeps that argument for its own ``TimeLimit`` wrapper and never passes it to the env, so
    the registered entry point reads it from ``make``'s frame: the env must not truncate earlier.
    """
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == "make" and frame.f_globals.get("__name__") == gymnasium.envs.registration.__name__:
            limit = frame.f_locals.get("max_episode_steps")
            return int(limit) if isinstance(limit, (int, np.integer)) and limit > 0 else None
        frame = frame.f_back
    return None


def from_registry(**kwargs: Any) -> HSAGymEnv:
    """The entry point of ``hsa_mjx/HSA-v0``: an :class:`HSAGymEnv` whose own episode limit is the
    ``max_episode_steps`` given to ``gymnasium.make`` (when one is; it must agree with
    ``termination__max_episode_steps`` when both are given)."""
    limit = time_limit_of_make()
    if limit is not None:
        own = kwargs.setdefault("termination__max_episode_steps", limit)
        if own != limit:
            raise ValueError(
                f"gymnasium.make got max_episode_steps={limit} and termination__max_episode_steps="
                f"{own}: give one (both set the episode's length)"
            )
    return HSAGymEnv(**kwargs)


class HSAGymEnv(gymnasium.Env):
    """A single :class:`~hsa_mjx.task.env.HSAEnv` as a ``gymnasium.Env`` (float32 numpy in and out).

    Args:
        config: preset name, YAML path or :class:`EnvConfig` (default ``"flat"``).
        render_mode: ``None``, ``"rgb_array"`` (offscreen ``mujoco.Renderer``) or ``"human"``
            (passive MuJoCo viewer; needs a display).
        width, height: size of ``rgb_array`` frames.
        camera: camera name or id in the asset (None: ``"track"``, which follows the robot;
            ``"overview"`` is fixed; -1 MuJoCo's free camera). The original's ``camera_name`` /
            ``camera_id`` are accepted for it.
        **overrides: config keys and/or the original ``HSAEnv`` arguments, as in
            :func:`hsa_mjx.make_env`. ``physics__backend`` chooses the physics as everywhere; its
            default ``auto`` runs the substeps in C MuJoCo on a CPU (``c``: same model, float64, about
            4x faster for one env than MJX there) with the env's own control, observation, reward and
            termination, and MJX on a GPU; ``jax`` forces MJX.

    ``step`` returns ``(obs, reward, terminated, truncated, info)``; ``info`` holds the reward
    components (``reward/<term>``), ``termination_reasons`` (list of names), ``distance_to_goal``,
    ``goal`` and ``is_success``. ``reset(options={"goal": (x, y)})`` places the goal by hand.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 50}

    def __init__(
        self,
        config: str | Path | EnvConfig = "flat",
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | int | None = None,
        **overrides: Any,
    ):
        from hsa_mjx.adapters.original_args import build_config

        self.render_mode = check_render_mode(render_mode)
        camera = pick_camera(camera, overrides)
        self.env: HSAEnv = HSAEnv(one_env_config(build_config(config, renderer=True, **overrides)))
        self._camera = check_camera(self.env.robot.mj_model, camera)
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / self.env.dt)))
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.env.observation_size,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (self.env.action_size,), np.float32)
        self._compile()
        self._buffers: tuple[jax.Array, ...] | None = None
        self._width, self._height = width, height
        self._renderer: StateRenderer | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; the same ``seed`` gives the same episode."""
        super().reset(seed=seed)
        key = episode_key(seed if seed is not None else int(self.np_random.integers(0, 2**31 - 1)))
        options = dict(options or {})
        goal = options.pop("goal", None)
        if goal is not None:
            goal = np.asarray(goal, np.float32)
            if goal.shape != (2,) or not np.all(np.isfinite(goal)):
                raise ValueError(f"options['goal'] must be a finite (x, y) pair, got {goal!r}")
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; valid options: ['goal']")
        buffers, out = self._reset_fn(key)
        if goal is not None:
            buffers, out = self._goal_fn(buffers, jnp.asarray(goal))
        self._buffers = buffers
        out = self._outputs.unpack_host(to_host(out))
        if self.render_mode == "human":
            self.render()
        return np.array(out["obs"], np.float32), self._info(out)

    def step(self, action):
        """Apply one normalised action of shape (8,) in [-1, 1]."""
        if self._buffers is None:
            raise RuntimeError("call reset() before step()")
        action = check_actions(action, self.action_space.shape)
        self._buffers, out = self._step_fn(self._buffers, action)
        out = self._outputs.unpack_host(to_host(out))  # one transfer per dtype for everything returned
        truncated = out["truncation"] > 0
        terminated = out["done"] > 0 and not truncated
        if self.render_mode == "human":
            self.render()
        return np.array(out["obs"], np.float32), float(out["reward"]), terminated, truncated, self._info(out)

    @staticmethod
    def _info(out: dict[str, Any]) -> dict[str, Any]:
        """The step's ``info`` from the host copy of ``_outputs``."""
        metrics = {k: float(v) for k, v in out["metrics"].items()}
        info: dict[str, Any] = {k: v for k, v in metrics.items() if k.startswith("reward/")}
        info["termination_reasons"] = [r for r in REASONS if metrics[f"termination/{r}"] > 0]
        info["is_success"] = metrics["termination/goal_reached"] > 0
        info["distance_to_goal"] = metrics["distance_to_goal"]
        info["goal"] = np.array(out["goal"], np.float32)
        info["nonfinite_action"] = metrics["nonfinite_action"] > 0
        return info

    def render(self):
        """``rgb_array``: an (H, W, 3) uint8 frame; ``human``: update the viewer window."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode= to make()")
            return None
        if self._buffers is None:
            raise RuntimeError("call reset() before render()")
        if self._renderer is None:
            self._renderer = StateRenderer(self.env, self.render_mode, self._width, self._height, self._camera)
        return self._renderer.render(self.state)

    @property
    def state(self) -> EnvState | None:
        """The env's current state (host copies of its arrays; None before ``reset``)."""
        return None if self._buffers is None else self._layout.unpack(jax.device_get(self._buffers))

    def _compile(self) -> None:
        """The jitted reset, step and goal placement over packed states (``hsa_mjx.adapters.packed``):
        each takes and returns one buffer per dtype instead of the state's ~150 arrays."""
        env = self.env
        shapes = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
        self._layout = layout = Packing(shapes)
        self._outputs = Packing(jax.eval_shape(_outputs, shapes))

        def packed(state: EnvState) -> tuple[tuple[jax.Array, ...], tuple[jax.Array, ...]]:
            return layout.pack(state), self._outputs.pack(_outputs(state))

        self._reset_fn = jax.jit(lambda key: packed(env.reset(key)))
        self._goal_fn = jax.jit(lambda buffers, goal: packed(env.set_goal(layout.unpack(buffers), goal)))
        if env.host_physics is None:
            self._step_fn = jax.jit(lambda buffers, action: packed(env.step(layout.unpack(buffers), action)))
        else:
            self._step_fn = HostStep(env, layout, shapes, packed)

    def close(self) -> None:
        """Release the renderer and viewer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class HostStep:
    """One step of a ``physics.backend: c`` env as two jitted halves around its C MuJoCo substeps.

    The env's ``step`` runs the substeps through a ``jax.pure_callback``, which costs more than the
    substeps themselves for one env. Here the first half (``HSAEnv.before_physics``) returns what the
    substeps read as one vector, the host runs them (``HostPhysics.run``) and the second half
    (``HSAEnv.after_physics``) takes the one vector they return: the same code as ``step``, no callback.
    What else passes between the halves stays in JAX arrays, never fetched.
    """

    def __init__(self, env: HSAEnv, layout: Packing, shapes: EnvState, packed: Any):
        host = env.host_physics
        self._run = host.run

        def first(buffers: tuple, action: jax.Array) -> tuple:
            state, call = env.before_physics(layout.unpack(buffers), action)
            middle = self._middle.pack(call.replace(data=None))
            return layout.pack(state), middle, host.inputs(call.data, call.targets, call.fields)

        def second(buffers: tuple, middle: tuple, out: jax.Array) -> tuple:
            state = layout.unpack(buffers)
            call = self._middle.unpack(middle).replace(data=state.pipeline_state.physics)
            return packed(env.after_physics(state, call, *host.outputs(call.data, out)))

        action = jax.ShapeDtypeStruct((env.action_size,), jnp.float32)
        call = jax.eval_shape(env.before_physics, shapes, action)[1]
        self._middle = Packing(call.replace(data=None))
        self._layout = host.layout(call.targets, call.fields)
        self._first, self._second = jax.jit(first), jax.jit(second)

    def __call__(self, buffers: tuple, action: jax.Array) -> tuple:
        """(the packed state after one step, the packed outputs), as the env's jitted ``step`` gives them."""
        buffers, middle, inputs = self._first(buffers, action)
        out = self._run(False, self._layout, np.asarray(inputs))
        return self._second(buffers, middle, out)


from_registry.metadata = HSAGymEnv.metadata  # what gymnasium.make reads from an entry point (render modes)

"""A device-batched Gymnasium ``VectorEnv``: N envs stepped in one jitted call, reset inside it.

The ``vector_entry_point`` of ``hsa_mjx/HSA-v0``::

    envs = gymnasium.make_vec("hsa_mjx/HSA-v0", num_envs=4096, vectorization_mode="vector_entry_point")
    envs = gymnasium.make_vec(..., output="jax")        # device arrays (torch: wrap in JaxToTorch)
    envs = gymnasium.make_vec(..., frame_skip=20, terrain__types=["craters"])   # as gymnasium.make

Autoreset mode ``SAME_STEP`` (the default): the step that ends an env's episode already returns
the first observation of its next episode, which was reset inside the same jitted call from the
env's own key (a new goal, and on the terrain scene a new terrain, at every reset). The terminal
observation and info are in ``info["final_obs"]`` / ``info["final_info"]``, masked by
``_final_obs`` / ``_final_info``. ``autoreset_mode="next_step"`` (Gymnasium's default, which its
vector wrappers such as ``NormalizeObservation`` need): the ending step returns the terminal
observation, and the next step returns the new episode's first observation with reward 0 and
both flags false, ignoring that env's action. docs/environment.md has the full contract.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.wrappers.array_conversion import array_conversion
from gymnasium.wrappers.vector import JaxToNumpy

from hsa_mjx.adapters.checks import check_actions
from hsa_mjx.adapters.gymnasium import pick_camera
from hsa_mjx.adapters.rendering import RENDER_MODES, StateRenderer, check_camera, check_render_mode
from hsa_mjx.batch.auto_reset import AutoResetEnv, BatchState, per_env_picker, select_sim
from hsa_mjx.config import EnvConfig
from hsa_mjx.sim.model import local_device
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.task.termination import REASONS
from hsa_mjx.task.types import EnvState

OUTPUTS = ("numpy", "jax")
AUTORESET_MODES = {"same_step": AutoresetMode.SAME_STEP, "next_step": AutoresetMode.NEXT_STEP}
SEED_LIMIT = 2**32  # per-env seeds are uint32: env i of reset(seed=s) uses (s + i) mod 2**32


def env_info(state: EnvState) -> dict[str, jax.Array]:
    """Per-env info arrays (leading axis: env) of a batch of env states."""
    metrics = state.metrics
    info = {k: v for k, v in metrics.items() if k.startswith("reward/")}
    info.update({f"termination/{r}": metrics[f"termination/{r}"] > 0 for r in REASONS})
    info["is_success"] = metrics["termination/goal_reached"] > 0
    info["distance_to_goal"] = metrics["distance_to_goal"]
    info["checkpoint_index"] = metrics["checkpoint_index"].astype(jnp.int32)
    info["nonfinite_action"] = metrics["nonfinite_action"] > 0
    info["goal"] = state.pipeline_state.task.goal_xy
    return info


def with_masks(info: dict[str, jax.Array], mask: jax.Array) -> dict[str, jax.Array]:
    """Gymnasium's vector info layout: every ``key`` gets a boolean ``_key`` saying which envs hold it."""
    return {**info, **{f"_{k}": mask for k in info}}


class HSAVectorEnv(VectorEnv):
    """``num_envs`` HSA envs as one ``gymnasium.vector.VectorEnv`` whose outputs are JAX arrays.

    Args:
        num_envs: batch size (>= 1).
        config: preset name, YAML path or :class:`EnvConfig` (default ``"flat"``).
        render_mode: ``None``, ``"rgb_array"`` or ``"human"``; ``render()`` draws env ``render_env``.
        width, height, camera: as in :class:`~hsa_mjx.adapters.gymnasium.HSAGymEnv`.
        render_env: index of the env that ``render()`` draws (an attribute; change it any time).
        check_finite: refuse non-finite actions with a ValueError (costs one device read of a
            bool per step when actions are JAX arrays). False lets the env zero them and count
            them in ``info["nonfinite_action"]``.
        autoreset_mode: ``"same_step"`` (default) or ``"next_step"`` (or the ``AutoresetMode``), above.
        **overrides: config keys and/or the original ``HSAEnv`` arguments (:func:`hsa_mjx.make_env`).

    ``step`` returns (obs (N, obs) float32, reward (N,) float32, terminated (N,) bool, truncated
    (N,) bool, info); see the module docstring and docs/environment.md for the autoreset and
    ``info`` contract. Wrap in :class:`NumpyOutput` (the default of ``make_vector_env``) for numpy.
    """

    metadata = {
        "render_modes": list(RENDER_MODES),
        "render_fps": 50,
        "autoreset_mode": AutoresetMode.SAME_STEP,
        "jax": True,
    }

    def __init__(
        self,
        num_envs: int,
        config: str | Path | EnvConfig = "flat",
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | int | None = None,
        render_env: int = 0,
        check_finite: bool = True,
        autoreset_mode: str | AutoresetMode = "same_step",
        **overrides: Any,
    ):
        from hsa_mjx.adapters.original_args import build_config

        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.num_envs = int(num_envs)
        if (
            isinstance(render_env, bool)
            or not isinstance(render_env, (int, np.integer))
            or not 0 <= render_env < num_envs
        ):
            raise ValueError(f"render_env must be an env index in 0..{num_envs - 1}, got {render_env!r}")
        self.render_mode = check_render_mode(render_mode)
        self.autoreset_mode = _check_autoreset_mode(autoreset_mode)
        camera = pick_camera(camera, overrides)
        self.env = HSAEnv(build_config(config, renderer=True, **overrides), num_envs=self.num_envs)
        self._camera = check_camera(self.env.robot.mj_model, camera)
        self.render_env, self.check_finite = render_env, check_finite
        self._render_size = (width, height)
        self.metadata = dict(
            self.metadata, render_fps=int(round(1.0 / self.env.dt)), autoreset_mode=self.autoreset_mode
        )
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (self.env.observation_size,), np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.env.action_size,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._batch = AutoResetEnv(self.env)
        # Every array passed to the jitted calls is committed to this device: a mix of committed
        # arrays (device_put, DLPack from torch) and uncommitted ones (jnp.asarray) would compile
        # the step once more.
        self._device = local_device()
        self._reset_fn = jax.jit(self._reset_outputs)
        self._step_fn = jax.jit(self._step_outputs)
        self._next_step_fn = jax.jit(self._next_step_outputs)
        self._pending: jax.Array | None = None  # next_step: envs whose episode ended on the last step
        self._state: BatchState | None = None
        self._all: jax.Array | None = None  # the all-true mask of the per-step info keys
        self._renderer: StateRenderer | None = None

    # ----- Gymnasium API -------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int] | None = None, options: dict | None = None):
        """Reset every env. ``seed``: an int s (env i uses s + i, as SyncVectorEnv and the single
        env seeded with s + i), a list of ``num_envs`` ints, or None (seeds from ``np_random``)."""
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; this vector env takes no options")
        seeds = self._seeds(seed)
        self._state, obs, info = self._reset_fn(jax.device_put(np.asarray(seeds, np.uint32), self._device))
        self._pending = jax.device_put(np.zeros(self.num_envs, bool), self._device)
        return obs, self._info(info)

    def step(self, actions: Any):
        """Step all envs with actions of shape (num_envs, 8) in [-1, 1]; finished envs restart."""
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        actions = check_actions(actions, self.action_space.shape, self.check_finite)
        if self.autoreset_mode is AutoresetMode.NEXT_STEP:
            self._state, self._pending, out = self._next_step_fn(
                self._state, self._pending, jax.device_put(actions, self._device)
            )
            obs, reward, terminated, truncated, info = out
            return obs, reward, terminated, truncated, self._info(info)
        self._state, out = self._step_fn(self._state, jax.device_put(actions, self._device))
        obs, reward, terminated, truncated, info, *final = out
        return obs, reward, terminated, truncated, self._info(info, *final)

    def render(self) -> np.ndarray | None:
        """A frame (H, W, 3) uint8 of env ``render_env`` (``rgb_array``), or the viewer updated (``human``)."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode= to make_vec()")
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        if not 0 <= self.render_env < self.num_envs:
            raise ValueError(f"render_env must be in 0..{self.num_envs - 1}, got {self.render_env!r}")
        if self._renderer is None:
            self._renderer = StateRenderer(self.env, self.render_mode, *self._render_size, self._camera)
        one = jax.tree.map(lambda x: x[self.render_env], self._state.env)
        return self._renderer.render(one)

    def close_extras(self, **kwargs: Any) -> None:
        """Release the renderer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ----- jitted pieces -------------------------------------------------------------------
    def _reset_outputs(self, seeds: jax.Array) -> tuple[BatchState, jax.Array, dict]:
        state = self._batch.reset(jax.vmap(jax.random.PRNGKey)(seeds))
        return state, state.env.obs, env_info(state.env)

    def _step_outputs(self, state: BatchState, actions: jax.Array) -> tuple[BatchState, tuple]:
        """The batch step; the info dicts come without their masks (``_info`` adds them outside jit,
        one mask array shared by all keys instead of one output buffer per key)."""
        new, nxt, episode = self._batch.step_with_final(state, actions, reset_metrics=True)
        done = nxt.done > 0
        truncated = nxt.info["truncation"] > 0
        final = env_info(nxt)
        final.update(episode_return=episode.ret, episode_length=episode.length.astype(jnp.int32))
        return new, (
            new.env.obs,
            nxt.reward,
            done & jnp.logical_not(truncated),
            truncated,
            env_info(new.env),
            nxt.obs,
            final,
            done,
        )

    def _next_step_outputs(self, state: BatchState, pending: jax.Array, actions: jax.Array):
        """``next_step``: envs that ended on the last step show the first state of their next episode
        (reset then, kept untouched since) with reward 0 and both flags false; the others step, and
        one that ends now shows its terminal state and is pending for the next call."""
        new, nxt, _ = self._batch.step_with_final(state, actions, reset_metrics=True)
        done = (nxt.done > 0) & jnp.logical_not(pending)
        truncated = (nxt.info["truncation"] > 0) & done
        kept = keep_pending(pending, state, new)
        shown = select_envs(pending, state.env, nxt)
        reward = jnp.where(pending, 0.0, nxt.reward)
        return kept, done, (shown.obs, reward, done & jnp.logical_not(truncated), truncated, env_info(shown))

    def _info(
        self, info: dict, final_obs: jax.Array | None = None, final: dict | None = None, done: jax.Array | None = None
    ) -> dict[str, Any]:
        """Gymnasium's vector info layout: every ``key`` with a boolean ``_key`` saying which envs hold it."""
        if self._all is None:
            self._all = jnp.ones(self.num_envs, bool)
        out = with_masks(info, self._all)
        if final is not None:
            out.update(final_obs=final_obs, _final_obs=done, final_info=with_masks(final, done), _final_info=done)
        return out

    # ----- seeds ---------------------------------------------------------------------------
    def _seeds(self, seed: int | Sequence[int] | None) -> np.ndarray:
        """One uint32 seed per env; a given seed also reseeds ``np_random`` (later seedless resets)."""
        if seed is None:
            return self.np_random.integers(0, 2**31 - 1, self.num_envs)
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            _check_seed(seed)
            self._np_random, self._np_random_seed = seeding.np_random(int(seed))
            return (int(seed) + np.arange(self.num_envs, dtype=np.uint64)) % SEED_LIMIT
        seeds = list(seed) if isinstance(seed, (list, tuple, np.ndarray)) else []
        if len(seeds) != self.num_envs:
            raise ValueError(f"seed must be an int, None or a list of num_envs={self.num_envs} ints, got {seed!r}")
        for s in seeds:
            _check_seed(s)
        self._np_random = np.random.Generator(np.random.PCG64([int(s) for s in seeds]))
        self._np_random_seed = -1
        return np.asarray(seeds, np.uint64)


def _check_autoreset_mode(mode: Any) -> AutoresetMode:
    """The ``AutoresetMode`` of a name or enum, or a ValueError listing the supported ones."""
    if isinstance(mode, AutoresetMode) and mode in AUTORESET_MODES.values():
        return mode
    if isinstance(mode, str) and mode.lower() in AUTORESET_MODES:
        return AUTORESET_MODES[mode.lower()]
    raise ValueError(f"autoreset_mode {mode!r} is not supported; use one of {list(AUTORESET_MODES)}")


def select_envs(mask: jax.Array, a: EnvState, b: EnvState) -> EnvState:
    """Env states taken from ``a`` where ``mask`` (one bool per env), else from ``b``."""
    rest = jax.tree.map(per_env_picker(mask), a.replace(pipeline_state=None), b.replace(pipeline_state=None))
    return rest.replace(pipeline_state=select_sim(mask, a.pipeline_state, b.pipeline_state))


def keep_pending(pending: jax.Array, old: BatchState, new: BatchState) -> BatchState:
    """The batch state after a step in which the ``pending`` envs did not take part."""
    pick = per_env_picker(pending)
    return new.replace(env=select_envs(pending, old.env, new.env), episode=jax.tree.map(pick, old.episode, new.episode))


def _check_seed(seed: Any) -> None:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < SEED_LIMIT:
        raise ValueError(f"each seed must be an integer in [0, 2**32), got {seed!r}")


class NumpyOutput(JaxToNumpy):
    """Gymnasium's ``JaxToNumpy`` for :class:`HSAVectorEnv`: outputs as numpy (read-only views on a
    CPU, host copies from a GPU); actions reach the env as given, so that it checks them on the host
    and sends them to the device once (``JaxToNumpy`` would first turn them into JAX arrays, and a
    wrong dtype would reach the check already converted)."""

    def __init__(self, env: HSAVectorEnv):
        super().__init__(env)
        self.metadata = dict(env.metadata, jax=False)

    def step(self, actions: Any):
        """Step with numpy (or any array-like) actions; numpy outputs."""
        return array_conversion(self.env.step(actions), xp=np)


def make_vector_env(num_envs: int = 1, output: str = "numpy", **kwargs: Any) -> VectorEnv:
    """The ``vector_entry_point``: :class:`HSAVectorEnv` with numpy (default) or JAX (``output="jax"``) outputs.

    Raises:
        ValueError: an unknown ``output``, ``num_envs`` < 1, or any constructor argument error.
    """
    if output not in OUTPUTS:
        raise ValueError(f"output must be one of {list(OUTPUTS)}, got {output!r}")
    env = HSAVectorEnv(num_envs, **kwargs)
    return env if output == "jax" else NumpyOutput(env)

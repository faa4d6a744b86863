"""hsa_mjx: the HSA crawling robot as a massively parallel JAX/MuJoCo MJX environment.

Public entry points:
    make_env(name_or_config, **overrides) -> HSAEnv   (Brax ``Env``: jittable reset/step)
    build_config(name_or_config, **overrides) -> EnvConfig   (what make_env builds, without building it)
    load_config(path) -> EnvConfig
    gymnasium.make("hsa_mjx/HSA-v0", ...)              (single env, registered on import)
    gymnasium.make_vec("hsa_mjx/HSA-v0", num_envs=N, vectorization_mode="vector_entry_point", ...)
                                                       (N envs stepped in one jitted call on the device)
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hsa_mjx.config import EnvConfig
    from hsa_mjx.task.env import HSAEnv


__version__ = "0.1.0"
# Public names, imported on first use: ``import hsa_mjx.deploy.policy_file`` (numpy only) must not import JAX.
_LAZY = {
    "build_config": "hsa_mjx.adapters.original_args",
    "PRESETS": "hsa_mjx.config",
    "EnvConfig": "hsa_mjx.config",
    "get_preset": "hsa_mjx.config",
    "load_config": "hsa_mjx.config",
    "with_overrides": "hsa_mjx.config",
    "HSAEnv": "hsa_mjx.task.env",
    "EnvState": "hsa_mjx.task.types",
    "SimState": "hsa_mjx.task.types",
    "TaskState": "hsa_mjx.task.types",
}


def __getattr__(name: str) -> Any:
    """Import a public name's module on first access."""
    if name not in _LAZY:
        raise AttributeError(f"module 'hsa_mjx' has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


def make_env(name_or_config: str | Path | EnvConfig = "flat", num_envs: int = 1, **overrides: Any) -> HSAEnv:
    """Build an :class:`HSAEnv`.

    Args:
        name_or_config: a preset name (see ``hsa_mjx.PRESETS``), a path to a YAML config, or an
            :class:`EnvConfig`.
        num_envs: how many envs ``reset``/``step`` will be vmapped over (sizes the contact buffer
            the envs of a batch share on the Warp backend; the JAX backend ignores it).
        **overrides: applied over the chosen config: dotted config keys with ``__`` for dots, e.g.
            ``reward__forward=3.0`` or ``goal__mode="fixed"``, and/or the original ``hsa_gym``
            ``HSAEnv`` arguments by their names, e.g. ``frame_skip=20`` or ``enable_terrain=True``
            (``hsa_mjx.adapters.original_args``; the table is in docs/environment.md).

    Raises:
        ValueError: unknown preset, argument, config key or value (the message lists the valid
            options), or an original argument and the config key it maps to both given.
        FileNotFoundError: a config path or the robot asset is missing.
    """
    from hsa_mjx.sim import gl

    gl.choose_platform()  # before mujoco is first imported (by the env below): offscreen frames when headless
    from hsa_mjx.adapters.original_args import build_config
    from hsa_mjx.task.env import HSAEnv

    return HSAEnv(build_config(name_or_config, **overrides), num_envs=num_envs)


def _register_gymnasium() -> None:
    """Register ``hsa_mjx/HSA-v0`` with Gymnasium when it is installed."""
    try:
        import gymnasium
    except ImportError:  # the adapter is optional
        return
    if "hsa_mjx/HSA-v0" not in gymnasium.registry:
        gymnasium.register(
            id="hsa_mjx/HSA-v0",
            entry_point="hsa_mjx.adapters.entry_points:single_env",
            vector_entry_point="hsa_mjx.adapters.entry_points:vector_env",
        )


_register_gymnasium()

__all__ = [
    "make_env",
    "build_config",
    "load_config",
    "EnvConfig",
    "HSAEnv",
    "EnvState",
    "SimState",
    "TaskState",
    "PRESETS",
    "__version__",
]

"""hsa_mjx: the HSA crawling robot as a massively parallel JAX/MuJoCo MJX environment.

Public entry points:
    make_env(name_or_config, **overrides) -> HSAEnv   (Brax ``Env``: jittable reset/step)
    load_config(path) -> EnvConfig
    gymnasium.make("hsa_mjx/HSA-v0", ...)              (single env, registered on import)
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hsa_mjx.config import PRESETS, EnvConfig, get_preset, load_config, with_overrides
    from hsa_mjx.env import HSAEnv
    from hsa_mjx.types import EnvState, SimState, TaskState

__version__ = "0.1.0"
# Public names, imported on first use: ``import hsa_mjx.policy`` (numpy only) must not import JAX.
_LAZY = {"PRESETS": "hsa_mjx.config", "EnvConfig": "hsa_mjx.config", "get_preset": "hsa_mjx.config",
         "load_config": "hsa_mjx.config", "with_overrides": "hsa_mjx.config", "HSAEnv": "hsa_mjx.env",
         "EnvState": "hsa_mjx.types", "SimState": "hsa_mjx.types", "TaskState": "hsa_mjx.types"}


def __getattr__(name: str) -> Any:
    """Import a public name's module on first access."""
    if name not in _LAZY:
        raise AttributeError(f"module 'hsa_mjx' has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


def make_env(name_or_config: str | Path | EnvConfig = "flat", **overrides: Any) -> HSAEnv:
    """Build an :class:`HSAEnv`.

    Args:
        name_or_config: a preset name (see ``hsa_mjx.PRESETS``), a path to a YAML config, or an
            :class:`EnvConfig`.
        **overrides: dotted config keys with ``__`` for dots, e.g. ``reward__forward=3.0`` or
            ``goal__mode="fixed"``, applied over the chosen config.

    Raises:
        ValueError: unknown preset, config key or value (the message lists the valid options).
        FileNotFoundError: a config path or the robot asset is missing.
    """
    from hsa_mjx.config import EnvConfig, get_preset, load_config, with_overrides
    from hsa_mjx.env import HSAEnv
    if isinstance(name_or_config, EnvConfig):
        config = name_or_config
    elif isinstance(name_or_config, Path) or str(name_or_config).endswith((".yaml", ".yml")):
        config = load_config(name_or_config)
    elif isinstance(name_or_config, str):
        config = get_preset(name_or_config)
    else:
        raise ValueError(f"make_env expects a preset name, a YAML path or an EnvConfig, got {name_or_config!r}")
    if overrides:
        config = with_overrides(config, **overrides)
    return HSAEnv(config)


def _register_gymnasium() -> None:
    """Register ``hsa_mjx/HSA-v0`` with Gymnasium when it is installed."""
    try:
        import gymnasium
    except ImportError:  # the adapter is optional
        return
    if "hsa_mjx/HSA-v0" not in gymnasium.registry:
        gymnasium.register(id="hsa_mjx/HSA-v0", entry_point="hsa_mjx.adapters.gymnasium:HSAGymEnv")


_register_gymnasium()

__all__ = ["make_env", "load_config", "EnvConfig", "HSAEnv", "EnvState", "SimState", "TaskState",
           "PRESETS", "__version__"]

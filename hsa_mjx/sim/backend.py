"""The physics backend: MJX's JAX implementation or its Warp implementation (MuJoCo Warp), behind one API.

Everything the env does with ``mjx.Data`` goes through public fields (``qpos``, ``xpos``,
``mocap_pos``, ``sensordata``, ...) and the few functions here, so one env code path runs on both:

- :func:`resolve` turns ``physics.backend`` (``jax | warp | auto``) into the implementation to use
  (``auto``: Warp on a CUDA GPU when ``warp-lang`` imports, else JAX) and refuses unknown names or a
  missing ``warp-lang`` before anything compiles;
- :func:`put_model` / :func:`make_data` build the MJX model and data for it (Warp's data holds one
  contact buffer shared by every env it is vmapped over, sized ``contacts_per_env x num_envs``);
- :func:`select` merges two states env by env (``Data.where``: Warp's shared buffers are kept, not
  selected, which a plain ``jax.tree.map`` would break).

``from hsa_mjx.sim.backend import mjx`` imports MJX without the "Failed to import warp" lines it prints
when ``warp-lang`` is absent (the CPU install does not need it).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import io
import sys
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.config import BACKENDS, EnvConfig

WARP_INSTALL = 'pip install -e ".[warp]"  (or: pip install warp-lang)'
_MJX_IMPORT_NOISE = ("Failed to import warp", "Failed to import mujoco_warp")
# Warp overflow flags (mujoco_warp OverflowType): contact, constraint and collision buffers that are
# too small print a warning (they matter: contacts are dropped); the solver's and line search's
# iteration caps (4-8 here, chosen against the fidelity guard) do not.
_WARP_ITERATION_FLAGS = (1 << 9) | (1 << 10)


def _import_mjx():
    """``mujoco.mjx`` imported with its missing-Warp messages filtered out of stdout."""
    if "mujoco.mjx" in sys.modules:
        return sys.modules["mujoco.mjx"]
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured):
        from mujoco import mjx as module
    for line in captured.getvalue().splitlines():
        if line.strip() and not line.startswith(_MJX_IMPORT_NOISE):
            print(line)
    return module


mjx = _import_mjx()


def warp_installed() -> bool:
    """Whether ``warp-lang`` is importable (checked without importing it)."""
    return importlib.util.find_spec("warp") is not None


def has_cuda_gpu(device: jax.Device | None = None) -> bool:
    """Whether ``device`` (default: this process's first device) is a CUDA GPU."""
    device = device or jax.local_devices()[0]
    return device.platform == "gpu" and "cuda" in getattr(device.client, "platform_version", "cuda").lower()


def resolve(name: str, device: jax.Device | None = None) -> str:
    """The physics (``"jax"``, ``"warp"`` or ``"c"``) for ``physics.backend = name`` on ``device``.

    ``auto``: MJX's Warp implementation on a CUDA GPU with ``warp-lang`` installed, else its JAX
    implementation (batches); :func:`for_one_env` makes ``auto`` C MuJoCo for one env on a CPU.
    ``c``: the substeps in C MuJoCo (``hsa_mjx.sim.host_physics``), one env after another.

    Raises:
        ValueError: an unknown name (the valid ones are listed), or ``warp`` without ``warp-lang``
            (the message says how to install it).
    """
    if name not in BACKENDS:
        raise ValueError(f"config key 'physics.backend' = {name!r} is not valid; choose one of {list(BACKENDS)}")
    if name == "auto":
        return "warp" if warp_installed() and has_cuda_gpu(device) else "jax"
    if name == "c":
        return name
    if name == "warp":
        if not warp_installed():
            raise ValueError(
                f"physics.backend 'warp' needs the warp-lang package, which is not installed: {WARP_INSTALL}; "
                "or use physics.backend 'jax'"
            )
        if not has_cuda_gpu(device):
            warnings.warn(
                "physics.backend 'warp' on a CPU runs MuJoCo Warp's CPU kernels: correct but slow "
                "(for tests); 'jax' is the CPU path",
                stacklevel=2,
            )
        _quiet_warp()
    return name


def for_one_env(name: str, device: jax.Device | None = None) -> str:
    """``physics.backend`` for an env stepped one at a time (Gymnasium, evaluation): ``auto`` becomes
    ``c`` on a CPU (C MuJoCo substeps: MJX is built for batches, one env of it is several times slower)."""
    if name == "auto" and (device or jax.local_devices()[0]).platform == "cpu":
        return "c"
    return name


def one_env_config(config: EnvConfig, device: jax.Device | None = None) -> EnvConfig:
    """``config`` with its ``physics.backend`` as :func:`for_one_env` resolves it."""
    chosen = for_one_env(config.physics.backend, device)
    if chosen == config.physics.backend:
        return config
    return dataclasses.replace(config, physics=dataclasses.replace(config.physics, backend=chosen))


def mjx_impl(physics: str) -> str:
    """The MJX implementation that holds the model and data of a resolved physics (``c``: JAX's)."""
    return "jax" if physics == "c" else physics


def _quiet_warp() -> None:
    """Keep Warp's banner and per-module load messages off the console (its warnings stay)."""
    import warp

    warp.config.quiet = True
    if hasattr(warp, "LOG_WARNING"):  # warp-lang >= 1.10 times module loads at log level INFO
        warp.config.log_level = warp.LOG_WARNING


def put_model(mj_model: mujoco.MjModel, backend: str, device: jax.Device) -> mjx.Model:
    """The MJX model of ``mj_model`` for ``backend`` on ``device`` (iteration-cap warnings off on Warp;
    on a GPU, MuJoCo Warp's kernel modules compiled first on parallel threads: :mod:`.warp_kernels`)."""
    if backend == "warp" and device.platform == "gpu":
        from hsa_mjx.sim import warp_kernels

        warp_kernels.prebuild(device)
    model = mjx.put_model(mj_model, impl=mjx_impl(backend), device=device)
    if backend == "warp":
        warp_opt = model.opt._impl
        model = model.replace(
            opt=model.opt.replace(
                _impl=warp_opt.replace(warn_overflow=int(warp_opt.warn_overflow) & ~_WARP_ITERATION_FLAGS)
            )
        )
    return model


def make_data(
    mj_model: mujoco.MjModel,
    backend: str,
    device: jax.Device,
    num_envs: int,
    contacts_per_env: int,
    constraints_per_env: int,
) -> mjx.Data:
    """Fresh MJX data for one env of ``backend``.

    On Warp, ``num_envs`` is how many envs this data will be vmapped over: their contacts share one
    buffer of ``contacts_per_env * num_envs`` slots, and each env has ``constraints_per_env`` rows
    (``physics.contacts_per_env`` / ``physics.constraints_per_env`` of the env config).
    The JAX implementation allocates every candidate contact statically and ignores all three.
    """
    if backend == "warp":
        return mjx.make_data(
            mj_model,
            impl="warp",
            device=device,
            naconmax=contacts_per_env * max(num_envs, 1),
            njmax=constraints_per_env,
        )
    return mjx.make_data(mj_model, impl="jax", device=device)


def select(done: jax.Array, fresh: mjx.Data, current: mjx.Data) -> mjx.Data:
    """``fresh`` where ``done`` else ``current``, per env (``done``: () inside vmap or (B,) outside)."""
    if np.ndim(done) == 0:
        return current.where(done, fresh)
    return jax.vmap(lambda d, a, b: a.where(d, b))(done, current, fresh)


def where(cond: jax.Array, a: Any, b: Any) -> Any:
    """``a`` where the scalar ``cond`` else ``b``, over any pytree of one env (inside ``vmap``); its
    ``mjx.Data`` are merged with :func:`select`."""

    def pick(x: Any, y: Any) -> Any:
        return select(cond, x, y) if isinstance(x, mjx.Data) else jnp.where(cond, x, y)

    return jax.tree.map(pick, a, b, is_leaf=lambda x: isinstance(x, mjx.Data))

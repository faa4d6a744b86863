"""MuJoCo Warp's kernel modules compiled ahead, on parallel threads, before the first step needs them.

On a machine whose Warp kernel cache is empty, the Warp backend compiles each kernel module the first
time it launches one, one module after another: on one H200 with this robot, 70 s of a training run's
115 s to its first update (``smooth`` 10 s, ``derivative`` 9 s, ``passive`` 9 s, ``sensor`` 7 s,
``forward`` 6 s; the tile kernels made for the model's sizes, 7 s each, among the rest).
:func:`prebuild` compiles the named modules (``MODULES``, the ones a step of this robot loads) on
threads, since Warp's compiler runs outside Python's lock, once per process and device; the modules
made per model at the first launch (the contact, constraint and solver kernels) still build then.
With a warm cache every module loads from disk in milliseconds and this costs nothing.

:func:`warm_up` steps one env of a model once, which builds the kernels MuJoCo Warp makes for the model's
sizes (the Cholesky tiles, the height-field collision: on one H200 about 25 s for the plane scene and 78 s
for the terrain scene, one after another). A training start on a GPU runs it in a helper process
(``hsa_mjx.task.warp_builder``); without one, on a thread while XLA compiles the training epoch ahead
(``train.devices.strategies.OneDevice.compile_ahead``), never while a program runs.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import warnings

import jax
import jax.numpy as jnp

from hsa_mjx.sim.backend import mjx

PACKAGE = "mujoco.mjx.third_party.mujoco_warp._src"
# the modules of MuJoCo Warp a step of this robot loads (measured from Warp's load log), heaviest first
MODULES = ("smooth", "derivative", "passive", "sensor", "forward", "solver", "support", "constraint")

_built: set[str] = set()
_lock = threading.Lock()
build_seconds: dict[str, float] = {}  # Warp device name -> the seconds its build ahead took (this process)


def warp_device(device: jax.Device) -> str:
    """Warp's name for the device a JAX device runs on (``cuda:N`` by its local ordinal, or ``cpu``)."""
    if device.platform == "gpu":
        return f"cuda:{device.local_hardware_id}"
    return "cpu"


def prebuild(device: jax.Device, workers: int | None = None) -> float | None:
    """Compile ``MODULES`` for ``device`` on ``workers`` threads (default: one a module, at most the CPU
    count), once per process and device: the seconds it took, or None when it had been done. A module
    not imported (another MuJoCo Warp) is skipped, and a failed build ignored, each with a warning: the
    first step builds what is missing, as without this."""
    import warp

    name = warp_device(device)
    with _lock:
        if name in _built:
            return None
        _built.add(name)
        start = time.perf_counter()
        modules = []
        for module in MODULES:
            if f"{PACKAGE}.{module}" not in sys.modules:
                warnings.warn(f"{PACKAGE}.{module} is not imported: its kernels build at the first step", stacklevel=2)
                continue
            modules.append(warp.get_module(f"{PACKAGE}.{module}"))
        count = workers or min(len(modules), os.cpu_count() or 1)
        try:
            warp.force_load(device=name, modules=modules, max_workers=count)
        except Exception as err:  # the head start is an optimisation: the first step builds what is missing
            warnings.warn(f"building MuJoCo Warp's kernels ahead failed ({err}); they build at first use", stacklevel=2)
        build_seconds[name] = time.perf_counter() - start
        return build_seconds[name]


def warm_up(model: mjx.Model, data: mjx.Data) -> float | None:
    """One physics step of one env (``data``, unbatched) of ``model``: the seconds, or None with a
    warning when it failed (the first training step then builds what is missing, as without this)."""
    start = time.perf_counter()
    try:
        jax.block_until_ready(_step_one_world(model, data))
    except Exception as err:  # a head start only
        warnings.warn(f"stepping MuJoCo Warp ahead failed ({err}); its kernels build at first use", stacklevel=2)
        return None
    return time.perf_counter() - start


@jax.jit
def _step_one_world(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """``data`` as a batch of one world (made by ``vmap``, as a vmapped reset makes the training's batch:
    Warp's buffers shared by all worlds, the contacts among them, stay unbatched, which a plain
    ``x[None]`` on every leaf would break) stepped once under ``vmap``."""
    batch = jax.vmap(lambda _: data)(jnp.zeros(1))
    return jax.vmap(mjx.step, in_axes=(None, 0))(model, batch)

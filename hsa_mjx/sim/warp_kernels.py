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
for the terrain scene, one after another). Without a helper process it runs on a thread while XLA
compiles the training epoch ahead (``train.devices.strategies.OneDevice.compile_ahead``), never while a
program runs.

:func:`build_for_model` builds the same kernels at once instead: a dry run of the step
(:func:`recording_launches`: every launch records its module and runs nothing) names every module the
step loads, with the block size it loads it at, and threads compile them together. Its step computes
nothing and a graph Warp captures during it is empty, so it runs only in a process that discards its
results: the helper a training start on a GPU launches (``hsa_mjx.task.warp_builder``), which leaves
the kernels in Warp's cache on disk for the training process.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import jax.numpy as jnp

from hsa_mjx.sim.backend import mjx

PACKAGE = "mujoco.mjx.third_party.mujoco_warp._src"
# the modules of MuJoCo Warp a step of this robot loads (measured from Warp's load log), heaviest first
MODULES = ("smooth", "derivative", "passive", "sensor", "forward", "solver", "support", "constraint")

_built: set[str] = set()
_lock = threading.Lock()
build_seconds: dict[str, float] = {}  # Warp device name -> the seconds its build ahead took (this process)
model_modules: dict[str, int] = {}  # Warp device name -> the modules build_for_model compiled (this process)
CUDA_BLOCK_DIM = 256  # Warp's block size for a CUDA launch that names none


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


def build_for_model(model: mjx.Model, data: mjx.Data, workers: int | None = None) -> float | None:
    """Every kernel module one step of ``model`` loads, named by a dry run of the step on one env
    (``data``, unbatched) and compiled at once on ``workers`` threads (default: one a module, at most the
    CPU count): the seconds (the count in ``model_modules``), or None with a warning when it failed. Only
    in a process that discards its results (the step computes nothing; the Warp graph it captures is empty)."""
    start = time.perf_counter()
    try:
        with recording_launches() as launches:
            jax.block_until_ready(_step_one_world(model, data))
        loads = list(launches.values())
        count = workers or max(1, min(len(loads), os.cpu_count() or 1))
        with ThreadPoolExecutor(count) as pool:  # Warp's compiler runs outside Python's lock
            list(pool.map(lambda load: load[0].load(load[2], load[1]), loads))
    except Exception as err:  # a head start only
        warnings.warn(f"building MuJoCo Warp's model kernels failed ({err}); they build at first use", stacklevel=2)
        return None
    for _, _, device in loads:
        model_modules[str(device)] = model_modules.get(str(device), 0) + 1
    return time.perf_counter() - start


@contextlib.contextmanager
def recording_launches() -> Iterator[dict]:
    """Within: Warp's kernel launches run nothing and record what they would load, ``{key: (module,
    block_dim, device)}`` (the yielded dict); ``capture_while`` runs its body once and ``capture_if``
    each branch once, so a dry run meets every kernel of a loop. A generic kernel (its overload chosen
    by the arguments' types) and an empty launch record nothing."""
    import warp

    launches: dict[tuple, tuple[Any, int, Any]] = {}
    saved = (warp.launch, warp.launch_tiled, warp.capture_while, warp.capture_if)

    def launch(kernel, dim, *args, device=None, stream=None, block_dim=None, **kwargs) -> None:
        device = args[4] if device is None and len(args) > 4 else device
        _record(launches, kernel, dim, stream.device if stream is not None else warp.get_device(device), block_dim)

    def launch_tiled(kernel, *args, dim, block_dim, device=None, stream=None, **kwargs) -> None:
        grid = [dim] if isinstance(dim, int) else list(dim)
        launch(kernel, [*grid, block_dim], *args, device=device, stream=stream, block_dim=block_dim)

    def capture_while(condition, while_body, stream=None, **kwargs) -> None:
        while_body(**kwargs)

    def capture_if(condition, on_true=None, on_false=None, stream=None, **kwargs) -> None:
        for branch in (on_true, on_false):
            if branch is not None:
                branch(**kwargs)

    replaced = (launch, launch_tiled, capture_while, capture_if)
    warp.launch, warp.launch_tiled, warp.capture_while, warp.capture_if = replaced
    try:
        yield launches
    finally:
        warp.launch, warp.launch_tiled, warp.capture_while, warp.capture_if = saved


def _record(launches: dict, kernel: Any, dim: Any, device: Any, block_dim: int | None) -> None:
    """Record the module a launch of ``kernel`` on ``device`` loads, at the block size Warp resolves
    (CUDA: the one asked for, else 256; CPU: 1 unless Warp's CPU blocks are on)."""
    import warp

    sizes = [dim] if isinstance(dim, int) else list(dim)
    if kernel.is_generic or any(int(n) == 0 for n in sizes):
        return
    if device.is_cpu:
        asked = block_dim if getattr(warp.config, "enable_cpu_blocks", False) and block_dim else 1
    else:
        asked = block_dim if block_dim and block_dim > 0 else CUDA_BLOCK_DIM
    launches[(id(kernel.module), asked, str(device))] = (kernel.module, asked, device)

"""How long a run takes to start, part by part, and whether it started with cold caches.

``Startup`` is made as ``train()`` begins and marks each part as it ends; the run's ``summary.json``
holds the result under ``startup`` (``benchmarks.scaling.time_to_target`` reports it):

- ``imports_s``: from the process's launch to ``train()`` (the interpreter, imports, the config);
- ``build_s``: the env and the learner built (the model, the terrain, the collection strategy);
- ``init_s``: the learner's first state (its program compiled) or the checkpoint restored;
- ``reset_s``: every env's first state (its program compiled);
- ``epoch_compile_s``: where the strategy compiles the training epoch ahead (one device), that compile
  and the wait for the Warp kernel helper beside it (or, without a helper, ``warp_warm_up_s``: MuJoCo
  Warp's kernels for the model built by one step on a thread meanwhile);
- ``first_update_s``: the first epoch: one epoch of collection and updates (and the training program's
  compile where it was not compiled ahead); ``compile_s`` estimates what the first epoch did beyond a
  later one's work (that compile, kernels built at first launch) as its excess over the second epoch;
- ``first_update_since_launch_s``: the process's age when the first update is done;
- ``xla``: what JAX reported compiling from the start to the record (``jax.monitoring`` events):
  tracing, lowering and XLA compile totals, the number of programs, and the compile seconds of the
  largest ones by name (a compile served by the persistent cache counts its load);
- ``warp_prebuild_s``: MuJoCo Warp's kernel modules built ahead on threads
  (``hsa_mjx.sim.warp_kernels``; None where none were: no Warp on a GPU);
- ``warp_builder``: on Warp on a GPU, the report of the helper process that built the kernels for the
  env (``hsa_mjx.task.warp_builder``): its ``prebuild_s``, ``warm_up_s`` (every module of a step built at
  once) and ``modules``, ``done_s`` from its launch,
  ``waited_s`` the wait for it, on one device on a thread beside the epoch's compile (None: no helper,
  or it failed and the first epoch built them).

A cache is cold when it is not set or holds nothing at the start: JAX's persistent compilation cache
(``jax_compilation_cache_dir``) and Warp's kernel cache (``WARP_CACHE_PATH``, else ``~/.cache/warp``,
counted only where Warp is installed). ``cold_caches`` is true when both are.
"""

from __future__ import annotations

import importlib.util
import os
import time
from pathlib import Path

import jax

from hsa_mjx.sim import warp_kernels

from .logger import process_age_s

# jax.monitoring's events of one compile: tracing to a jaxpr, lowering to MLIR, XLA's compile (or cache load)
EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "compile_s",
}
LARGEST = 6  # programs named in the record


def cache_entries(path: str | Path | None) -> int | None:
    """Files under a cache folder (``None``: no folder set or none there)."""
    if not path or not Path(path).is_dir():
        return None
    return sum(len(files) for _, _, files in os.walk(path))


def warp_cache_dir() -> Path | None:
    """Warp's kernel cache folder, where Warp is installed (``None`` otherwise)."""
    if importlib.util.find_spec("warp") is None:
        return None
    return Path(os.environ.get("WARP_CACHE_PATH") or Path.home() / ".cache" / "warp")


class CompileLog:
    """A ``jax.monitoring`` listener: the seconds of each compile event, by kind and by program."""

    def __init__(self):
        self.totals = dict.fromkeys(EVENTS.values(), 0.0)
        self.programs: dict[str, float] = {}

    def __call__(self, event: str, seconds: float, **kwargs) -> None:
        kind = EVENTS.get(event)
        if kind is None:
            return
        self.totals[kind] += seconds
        if kind == "compile_s":
            name = str(kwargs.get("fun_name", "?"))
            self.programs[name] = self.programs.get(name, 0.0) + seconds

    def record(self) -> dict:
        """The totals, the number of programs and the largest ones' compile seconds."""
        largest = sorted(self.programs.items(), key=lambda item: -item[1])[:LARGEST]
        return {
            **{k: round(v, 2) for k, v in self.totals.items()},
            "programs": len(self.programs),
            "largest": {name: round(v, 2) for name, v in largest},
        }


class Startup:
    """The start-up parts of one training call (seconds), marked in order, and the caches it found."""

    def __init__(self):
        self.parts: dict[str, float] = {"imports_s": process_age_s()}
        self._last = time.perf_counter()
        self.compiles = CompileLog()
        jax.monitoring.register_event_duration_secs_listener(self.compiles)
        self._listening = True
        self._prebuilt = dict(warp_kernels.build_seconds)
        self.warp_builder: dict | None = None  # the Warp kernel helper's report, where one ran
        warp = warp_cache_dir()
        self.caches = {
            "jax_compilation_cache": cache_entries(jax.config.jax_compilation_cache_dir),
            "warp_kernel_cache": None if warp is None else cache_entries(warp),
        }

    def mark(self, part: str) -> None:
        """The part that ends now took the time since the last mark."""
        now = time.perf_counter()
        self.parts[part], self._last = now - self._last, now

    def epoch(self, seconds: float) -> None:
        """An epoch's time: the first's holds the training program's compile, the second's shows how much."""
        if "first_update_s" not in self.parts:
            self.parts["first_update_s"] = seconds
            self.parts["first_update_since_launch_s"] = process_age_s()
        elif "compile_s" not in self.parts:
            self.parts["compile_s"] = max(self.parts["first_update_s"] - seconds, 0.0)

    def record(self) -> dict:
        """The ``startup`` block of ``summary.json`` (compiles counted until now; the listener stops)."""
        if self._listening:
            jax.monitoring.unregister_event_duration_listener(self.compiles)
            self._listening = False
        parts = {k: round(v, 3) for k, v in self.parts.items()}
        built = [v for k, v in warp_kernels.build_seconds.items() if k not in self._prebuilt]
        return {
            **parts,
            "xla": self.compiles.record(),
            "warp_prebuild_s": round(sum(built), 2) if built else None,
            "warp_builder": self.warp_builder,
            "caches": self.caches,
            "cold_caches": all(not n for n in self.caches.values()),
        }

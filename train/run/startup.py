"""How long a run takes to start, part by part, and whether it started with cold caches.

``Startup`` is made as ``train()`` begins and marks each part as it ends; the run's ``summary.json``
holds the result under ``startup`` (``benchmarks.scaling.time_to_target`` reports it):

- ``imports_s``: from the process's launch to ``train()`` (the interpreter, imports, the config);
- ``build_s``: the env and the learner built (the model, the terrain, the collection strategy);
- ``init_s``: the learner's first state (its program compiled) or the checkpoint restored;
- ``reset_s``: every env's first state (its program compiled);
- ``first_update_s``: the first epoch: the training program compiled, then one epoch of collection and
  updates; ``compile_s`` estimates the compile as that minus the second epoch's time;
- ``first_update_since_launch_s``: the process's age when the first update is done.

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

from .logger import process_age_s


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


class Startup:
    """The start-up parts of one training call (seconds), marked in order, and the caches it found."""

    def __init__(self):
        self.parts: dict[str, float] = {"imports_s": process_age_s()}
        self._last = time.perf_counter()
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
        """The ``startup`` block of ``summary.json``."""
        parts = {k: round(v, 3) for k, v in self.parts.items()}
        return {**parts, "caches": self.caches, "cold_caches": all(not n for n in self.caches.values())}

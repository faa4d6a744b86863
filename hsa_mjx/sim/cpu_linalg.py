"""Work around a deadlock of batched LAPACK calls in jaxlib's CPU backend.

On the CPU, JAX lowers ``cholesky`` and ``triangular_solve`` to LAPACK custom calls that split a
batch over XLA's intra-op thread pool and block until the pieces finish. When two such calls run
at once and the pool is small (the 2-core CI machine), both wait for work that no free thread can
pick up: a vmapped MJX step over a large batch (44 or more envs: jaxlib splits a batch once it exceeds
2e5 FLOP, i.e. 44 of the 24 x 24 Cholesky factorizations) hangs
forever at 0 % CPU (seen with gdb: two threads in ``jax::ParallelBatchMap`` ->
``BlockingCounter::Wait`` under ``lapack_spotrf_ffi``; jaxlib 0.10.2). MJX calls Cholesky for the
mass matrix and in the Newton solver of every step.

``use_xla_linalg_on_cpu()`` makes the CPU use XLA's own Cholesky and triangular-solve ops (the
lowering JAX uses on other platforms; XLA expands them into plain loops), which have no such
pool, for batches above ``LAPACK_MAX_BATCH`` matrices; smaller batches (never split over the pool,
and about 3x faster with LAPACK: 19 vs 64 ms per step of 4 envs) keep LAPACK. It changes only the
CPU lowering, never GPU code; results agree with LAPACK to float32 rounding. ``hsa_mjx.sim.model``
(which every MJX path imports) applies it on import; set ``HSA_MJX_CPU_LAPACK=1`` to keep JAX's default. It relies on JAX internals and
does nothing (returns False) where they differ.
"""

from __future__ import annotations

import os

import math

_installed = False
LAPACK_MAX_BATCH = 32  # below the 44-matrix split point of jaxlib's LAPACK kernels


def _by_batch(lapack_rule, xla_rule):
    """A lowering rule that uses LAPACK for small batches and XLA's op for large ones."""
    def rule(ctx, *args, **kwargs):
        batch = math.prod(ctx.avals_in[0].shape[:-2])
        chosen = lapack_rule if batch <= LAPACK_MAX_BATCH else xla_rule
        return chosen(ctx, *args, **kwargs)
    return rule


def use_xla_linalg_on_cpu() -> bool:
    """Lower Cholesky and triangular solves on the CPU to XLA ops; True if the lowering is active."""
    global _installed
    if _installed or os.environ.get("HSA_MJX_CPU_LAPACK") == "1":
        return _installed
    try:
        from jax._src.interpreters import mlir
        from jax._src.lax import linalg
        mlir.register_lowering(linalg.cholesky_p, _by_batch(linalg._cholesky_cpu_lowering,
                                                            linalg._cholesky_lowering), platform="cpu")
        mlir.register_lowering(linalg.triangular_solve_p, _by_batch(linalg._triangular_solve_cpu_lower,
                                                                    linalg._triangular_solve_lowering), platform="cpu")
    except (ImportError, AttributeError):  # a JAX version with other internals: keep its default
        return False
    _installed = True
    return True

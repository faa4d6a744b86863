"""CPU lowerings of ``cholesky`` and ``triangular_solve`` that cannot deadlock on a small thread pool.

JAX lowers both to LAPACK custom calls that split a large batch over XLA's intra-op thread pool and
block until the pieces finish; two such calls at once on a small pool can wait forever for each
other, and MJX calls Cholesky in every step. ``use_xla_linalg_on_cpu()`` registers CPU lowerings
(through JAX's public ``jax.interpreters.mlir``, ``jax.ffi`` and ``jax.extend.mlir`` APIs and
jaxlib's LAPACK target names) that emit XLA's own ops, plain loops with no pool, for batches above
``LAPACK_MAX_BATCH`` matrices; smaller batches, never split, keep the faster LAPACK kernels, a failed
factorisation giving NaN as in JAX. GPU code is untouched; results agree with LAPACK to float32
rounding. Where it was seen, and the measurements behind the batch limit: docs/speed.md.

Importing this module changes nothing: ``hsa_mjx.sim.model.load_robot``, which builds every env,
calls ``use_xla_linalg_on_cpu()`` (once per process); ``HSA_MJX_CPU_LAPACK=1`` keeps JAX's default.
"""

from __future__ import annotations

import math
import os

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.mlir import ir
from jax.extend.mlir.dialects import stablehlo as hlo
from jax.interpreters import mlir
from jax.lax import linalg
from jaxlib import lapack  # the LAPACK kernels' names, loaded on first use as JAX's own lowering does

LAPACK_MAX_BATCH = 32  # below the batch at which jaxlib's LAPACK kernels split over the pool (docs/speed.md)
_LAPACK_TYPES = (np.dtype(np.float32), np.dtype(np.float64))  # real types: what MJX uses
_installed = False


def _uses_lapack(aval) -> bool:
    """Whether a batch of matrices keeps JAX's LAPACK kernels (a small batch of a real type)."""
    return math.prod(aval.shape[:-2]) <= LAPACK_MAX_BATCH and np.dtype(aval.dtype) in _LAPACK_TYPES


def _column_major(ndim: int) -> tuple[int, ...]:
    """Major-to-minor axis order of a batch of column-major matrices (what LAPACK reads)."""
    return (*range(ndim - 2), ndim - 1, ndim - 2)


def _char(c: str) -> np.uint8:
    """A LAPACK character option as the FFI handlers take it."""
    return np.uint8(ord(c))


def _lapack_cholesky(x: jax.Array) -> jax.Array:
    """Lower Cholesky factors by LAPACK ``potrf`` (NaN where a matrix is not positive definite)."""
    layout = _column_major(x.ndim)
    factor, info = jax.ffi.ffi_call(
        lapack.prepare_lapack_call("potrf_ffi", x.dtype),
        (jax.ShapeDtypeStruct(x.shape, x.dtype), jax.ShapeDtypeStruct(x.shape[:-2], jnp.int32)),
        input_layouts=[layout],
        output_layouts=[layout, None],
        input_output_aliases={0: 0},
    )(x, uplo=_char("L"))
    return jnp.where((info == 0)[..., None, None], factor, jnp.nan)


def _cholesky_rule(ctx, x, **params):
    """LAPACK for small real batches, XLA's op otherwise (the wrapper keeps the lower triangle)."""
    if _uses_lapack(ctx.avals_in[0]):
        return mlir.lower_fun(_lapack_cholesky, multiple_results=False)(ctx, x)
    return [hlo.cholesky(x, lower=ir.BoolAttr.get(True))]


def _lapack_triangular_solve(a, b, *, left_side, lower, transpose_a, unit_diagonal):
    """``op(a) x = b`` (or ``x op(a) = b``) by LAPACK ``trsm``, for real ``a``."""
    return jax.ffi.ffi_call(
        lapack.prepare_lapack_call("trsm_ffi", a.dtype),
        jax.ShapeDtypeStruct(b.shape, b.dtype),
        input_layouts=[_column_major(a.ndim), _column_major(b.ndim)],
        output_layouts=_column_major(b.ndim),
        input_output_aliases={1: 0},
    )(
        a,
        b,
        side=_char("L" if left_side else "R"),
        uplo=_char("L" if lower else "U"),
        trans_x=_char("T" if transpose_a else "N"),
        diag=_char("U" if unit_diagonal else "N"),
    )


def _triangular_solve_rule(ctx, a, b, *, left_side, lower, transpose_a, conjugate_a, unit_diagonal, **params):
    """LAPACK for small real batches, XLA's op otherwise (conjugation applies to complex ``a`` only)."""
    if _uses_lapack(ctx.avals_in[0]) and _uses_lapack(ctx.avals_in[1]):

        def solve(a, b):
            return _lapack_triangular_solve(
                a, b, left_side=left_side, lower=lower, transpose_a=transpose_a, unit_diagonal=unit_diagonal
            )

        return mlir.lower_fun(solve, multiple_results=False)(ctx, a, b)
    if conjugate_a and not transpose_a:  # only complex types: conjugate first, then solve plainly

        def solve(a, b):
            return linalg.triangular_solve(
                jnp.conj(a), b, left_side=left_side, lower=lower, unit_diagonal=unit_diagonal
            )

        return mlir.lower_fun(solve, multiple_results=False)(ctx, a, b)
    transpose = ("ADJOINT" if conjugate_a else "TRANSPOSE") if transpose_a else "NO_TRANSPOSE"
    return [
        hlo.triangular_solve(
            a,
            b,
            ir.BoolAttr.get(left_side),
            ir.BoolAttr.get(lower),
            ir.BoolAttr.get(unit_diagonal),
            hlo.TransposeAttr.get(transpose),
        )
    ]


def use_xla_linalg_on_cpu() -> bool:
    """Lower large batches of Cholesky and triangular solves on the CPU to XLA ops; True if active."""
    global _installed
    if _installed or os.environ.get("HSA_MJX_CPU_LAPACK") == "1":
        return _installed
    mlir.register_lowering(linalg.cholesky_p, _cholesky_rule, platform="cpu")
    mlir.register_lowering(linalg.triangular_solve_p, _triangular_solve_rule, platform="cpu")
    _installed = True
    return True

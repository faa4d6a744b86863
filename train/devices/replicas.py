"""Where the learner's state lives on several devices: copies along a leading device axis, and the
``pmap`` that compiles across processes (no zero-size array in or baked into its program).

Shared by the collection strategies (``train.devices.strategies``, ``train.devices.thread_per_device``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import ClosedJaxpr, jaxpr_as_fun

from ..learners.ppo.learner import AXIS
from . import compat


def _dtype(leaf: Any) -> np.dtype:
    """A leaf's dtype (an array's own, a Python number's as NumPy makes it)."""
    return leaf.dtype if hasattr(leaf, "dtype") else np.result_type(leaf)


def _is_empty(leaf: Any) -> bool:
    """Whether a leaf is an array with no elements (a dimension of size 0)."""
    return int(np.prod(np.shape(leaf))) == 0 and np.ndim(leaf) > 0


class PmapWithoutEmpty:
    """``jax.pmap(fn, **kwargs)`` whose compiled program has no array of zero size as an argument or a constant.

    A ``pmap`` spanning several processes on GPUs segfaults XLA's compile when its program takes
    a zero-size array as an argument or holds one as a constant (JAX 0.11, two processes of one
    H100 each: ``pmap(lambda x: x + e.sum())`` with ``e`` of shape (3, 0) as argument or closure); one
    process with several GPUs, and CPU processes, compile it. MJX's model and data have such
    fields (no equality constraints, no activations). So each call passes only the non-empty leaves
    of every argument, and ``fn`` is traced once per argument layout to a jaxpr whose zero-size
    constants become zeros made inside the program; ``fn`` sees its arguments unchanged and its
    outputs are returned as it makes them. ``axis_name``, ``donate_argnums`` and the other keywords
    mean what they mean to ``jax.pmap``.
    """

    def __init__(self, fn: Callable, axis_name: str, **pmap_kwargs: Any):
        self._fn, self._axis, self._kwargs = fn, axis_name, pmap_kwargs
        self._pmapped: dict = {}

    def __call__(self, *args: Any) -> Any:
        layout, kept = self._split(args)
        return self._program(layout, kept)(*kept)

    def lower(self, *args: Any) -> jax.stages.Lowered:
        """The program a call with ``args`` runs, lowered (to inspect it)."""
        layout, kept = self._split(args)
        return self._program(layout, kept).lower(*kept)

    @staticmethod
    def _split(args: tuple) -> tuple[tuple, list]:
        """(the layout: every argument's tree and its empty leaves' places, shapes and dtypes;
        every argument's non-empty leaves, the ones passed)."""
        flat = [jax.tree.flatten(arg) for arg in args]
        kept = [[leaf for leaf in leaves if not _is_empty(leaf)] for leaves, _ in flat]
        holes = tuple(
            tuple((i, np.shape(leaf)[1:], _dtype(leaf)) for i, leaf in enumerate(leaves) if _is_empty(leaf))
            for leaves, _ in flat
        )
        return (tuple(treedef for _, treedef in flat), holes), kept

    def _program(self, layout: tuple, kept: list) -> Callable:
        """The pmapped program for one argument layout, built at its first call."""
        if layout not in self._pmapped:
            self._pmapped[layout] = self._build(*layout, kept)
        return self._pmapped[layout]

    def _build(self, treedefs: tuple, holes: tuple, kept: list) -> Callable:
        """The pmapped program for one argument layout (tracing ``fn`` once for its constants)."""

        def refilled(*kept_leaves: list) -> Any:
            args = []
            for leaves, treedef, empty in zip(kept_leaves, treedefs, holes):
                leaves = list(leaves)
                for i, shape, dtype in empty:  # in increasing position: each insert lands where it was
                    leaves.insert(i, jnp.zeros(shape, dtype))
                args.append(jax.tree.unflatten(treedef, leaves))
            return self._fn(*args)

        per_device = [[jax.ShapeDtypeStruct(np.shape(x)[1:], _dtype(x)) for x in leaves] for leaves in kept]
        size = np.shape(jax.tree.leaves(kept)[0])[0] * jax.process_count()  # the devices the pmap spans
        traced, out_shape = jax.make_jaxpr(refilled, axis_env=[(self._axis, size)], return_shape=True)(*per_device)
        out_tree = jax.tree.structure(out_shape)

        def program(*kept_leaves: list) -> Any:
            consts = [jnp.zeros(np.shape(c), _dtype(c)) if _is_empty(c) else c for c in traced.consts]
            out = jaxpr_as_fun(ClosedJaxpr(traced.jaxpr, consts))(*jax.tree.leaves(kept_leaves))
            return jax.tree.unflatten(out_tree, out)

        return jax.pmap(program, axis_name=self._axis, **self._kwargs)


def replicate(tree: Any, devices: Sequence[jax.Device]) -> Any:
    """Copy a pytree onto each device along a new leading axis, laid out as pmapped functions return it.

    ``device_put_replicated`` places the copies on a mesh axis of its own name; a pmapped function's
    outputs live on its ``devices`` axis, and feeding the former to the first epoch and the latter to
    the second made ``pmap`` compile the epoch twice. A pmapped identity puts the copies on that axis.
    """
    return PmapWithoutEmpty(lambda x: x, axis_name=AXIS)(compat.device_put_replicated(tree, list(devices)))


def first_copy(tree: Any) -> Any:
    """The first device's copy of a pytree with a leading device axis."""
    return jax.tree.map(lambda x: x[0], tree)

"""A pytree held as one flat buffer per dtype, for a jitted function called once per env step.

Calling a jitted function costs a few microseconds per array it takes and returns. The env state is
about 150 arrays, so one Gymnasium step spent more time passing them in and out than stepping the
task itself. :class:`Packing` lays a fixed pytree structure out as one 1-D buffer per dtype (float32,
int32, ...) and back, with static slices: inside ``jit`` packing is one concatenation per dtype and
unpacking costs nothing; on the host, unpacking a fetched buffer gives numpy views without copies.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class Slot(NamedTuple):
    """Where one leaf lives: its dtype's buffer, the offset in it, its shape and size."""

    buffer: int
    offset: int
    shape: tuple[int, ...]
    size: int


class Packing:
    """The layout of one pytree structure (leaves' shapes and dtypes fixed) as one buffer per dtype.

    Args:
        example: a pytree of arrays or ``jax.ShapeDtypeStruct`` (e.g. from ``jax.eval_shape``).
    """

    def __init__(self, example: Any):
        leaves, self.treedef = jax.tree_util.tree_flatten(example)
        self.dtypes = tuple(sorted({np.dtype(leaf.dtype) for leaf in leaves}, key=str))
        sizes = [0] * len(self.dtypes)
        slots = []
        for leaf in leaves:
            buffer, shape = self.dtypes.index(np.dtype(leaf.dtype)), tuple(leaf.shape)
            size = int(np.prod(shape, dtype=np.int64))
            slots.append(Slot(buffer, sizes[buffer], shape, size))
            sizes[buffer] += size
        self.slots, self.sizes = tuple(slots), tuple(sizes)

    def pack(self, tree: Any, xp: Any = jnp) -> tuple[Any, ...]:
        """The tree's leaves concatenated per dtype: traceable with ``xp=jax.numpy``, numpy buffers on
        the host with ``xp=numpy``. The tree must have this layout."""
        leaves = self.treedef.flatten_up_to(tree)
        parts: list[list[Any]] = [[] for _ in self.dtypes]
        for slot, leaf in zip(self.slots, leaves):
            if xp is jnp or leaf.shape != slot.shape:  # checked where it costs nothing: at trace time
                leaf = xp.asarray(leaf)
                if leaf.shape != slot.shape or leaf.dtype != self.dtypes[slot.buffer]:
                    raise ValueError(
                        f"leaf of shape {leaf.shape} and dtype {leaf.dtype} where the layout has "
                        f"{slot.shape} {self.dtypes[slot.buffer]}"
                    )
            parts[slot.buffer].append(leaf.ravel())
        return tuple(
            xp.concatenate(p).astype(d, copy=False) if p else xp.zeros((0,), d) for p, d in zip(parts, self.dtypes)
        )

    def _check_count(self, buffers: tuple[Any, ...]) -> None:
        """Raise ValueError naming the layout's buffers when ``buffers`` has another count."""
        if len(buffers) != len(self.dtypes):
            names = [str(d) for d in self.dtypes]
            raise ValueError(f"expected {len(self.dtypes)} buffers ({names}), got {len(buffers)}")

    def unpack(self, buffers: tuple[Any, ...]) -> Any:
        """The tree back from its buffers: jax arrays inside ``jit``, numpy views of numpy buffers."""
        self._check_count(buffers)
        leaves = [buffers[s.buffer][s.offset : s.offset + s.size].reshape(s.shape) for s in self.slots]
        return jax.tree_util.tree_unflatten(self.treedef, leaves)

    def unpack_host(self, buffers: tuple[np.ndarray, ...]) -> Any:
        """The tree back from numpy buffers with each 0-d leaf a Python scalar (``tolist``) and the
        others numpy views: what a host reads field by field, at a fraction of :meth:`unpack`'s cost
        (one small array per 0-d leaf there)."""
        self._check_count(buffers)
        lists = [buffer.tolist() for buffer in buffers]
        leaves = [
            lists[s.buffer][s.offset]
            if not s.shape
            else buffers[s.buffer][s.offset : s.offset + s.size].reshape(s.shape)
            for s in self.slots
        ]
        return jax.tree_util.tree_unflatten(self.treedef, leaves)


def to_host(buffers: tuple[Any, ...]) -> tuple[np.ndarray, ...]:
    """Fetched buffers as numpy arrays (read-only; on a CPU, views of the jax arrays' buffers: copy what
    is handed out). ``np.asarray`` reads a CPU jax array in about 2 microseconds where
    ``jax.device_get`` takes about 15 (one env's step fetches two sets)."""
    return tuple(np.asarray(buffer) for buffer in buffers)

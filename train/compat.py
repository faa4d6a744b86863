"""Compatibility with current JAX for Brax 0.14.2.

Brax 0.14.2's trainers (``ppo``, ``sac``, ``apg``, ``training/pmap.py``) call
``jax.device_put_replicated``, which JAX 0.10 removed: they fail with ``AttributeError`` right
after the first reset. hsa_mjx's own trainer (``train.learner``) does not need it; ``install()``
restores the function, so Brax's trainers also run on our env. It is a no-op where JAX still has
the function. Remove this module once a Brax release with the upstream fix is required.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def device_put_replicated(tree: Any, devices: Sequence[jax.Device]) -> Any:
    """Stack ``len(devices)`` copies of every leaf on a new leading axis, one copy per device."""
    devices = list(devices)
    sharding = NamedSharding(Mesh(np.array(devices), ("replica",)), PartitionSpec("replica"))

    def put(leaf: Any) -> jax.Array:
        stacked = np.stack([np.asarray(leaf)] * len(devices))
        return jax.device_put(stacked, sharding)

    return jax.tree.map(put, tree)


def install() -> bool:
    """Define ``jax.device_put_replicated`` if this JAX lacks it; return True if it was added."""
    if hasattr(jax, "device_put_replicated"):
        return False
    jax.device_put_replicated = device_put_replicated
    return True

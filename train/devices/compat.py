"""``device_put_replicated`` for current JAX: copies of a pytree stacked one per device.

JAX 0.10 removed ``jax.device_put_replicated``. The trainer's own replication
(``train.devices.replicas.replicate``) uses :func:`device_put_replicated` here. Brax 0.14.2's trainers
(``ppo``, ``sac``, ``apg``, ``training/pmap.py``) still call the JAX function and fail with
``AttributeError`` right after the first reset; :func:`install` defines it for them (a no-op
where JAX still has it), so Brax's own trainers also run on our env (``tests/test_train_pieces.py``).
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

"""Action checks shared by the Gymnasium adapters: shape, dtype and finiteness before anything runs."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def _expected(shape: tuple[int, ...]) -> str:
    return f"a float array of shape {shape} (float32; other float dtypes are converted) with values in [-1, 1]"


def check_actions(actions: Any, shape: tuple[int, ...], check_finite: bool = True) -> np.ndarray | jax.Array:
    """Return ``actions`` as float32 (a JAX array stays one) or raise ValueError naming shape and dtype.

    Host input (numpy, lists) is checked on the host. A JAX array is checked from its metadata;
    its finiteness costs one device-to-host read of a single bool (``check_finite=False`` skips
    it: the env then zeroes non-finite entries and counts them in ``nonfinite_action``).
    """
    if type(actions) is np.ndarray and actions.dtype == np.float32 and actions.shape == tuple(shape):
        if not check_finite or np.isfinite(actions).all():  # a learner's usual action, checked in ~2 us
            return actions.copy()
    expected = _expected(shape)
    on_device = isinstance(actions, jax.Array)
    if not on_device:
        try:
            actions = np.asarray(actions)
        except (ValueError, TypeError) as err:
            raise ValueError(f"actions must be {expected}; got {type(actions).__name__} ({err})") from None
    dtype = np.dtype(actions.dtype)
    if dtype.kind != "f":
        raise ValueError(f"actions must be {expected}; got dtype {dtype}")
    if tuple(actions.shape) != tuple(shape):
        raise ValueError(f"actions must be {expected}; got shape {tuple(actions.shape)}")
    if check_finite:
        finite = bool(jnp.all(jnp.isfinite(actions))) if on_device else bool(np.all(np.isfinite(actions)))
        if not finite:
            bad = np.argwhere(~np.isfinite(np.asarray(actions)))[:8].tolist()
            raise ValueError(f"actions must be {expected}; got non-finite values at indices {bad}")
    return actions.astype(jnp.float32) if on_device else actions.astype(np.float32)

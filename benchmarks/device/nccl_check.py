"""Smallest multi-GPU check: a pmapped psum and all_gather over every local device (exit 0 = fine).

Run on the GPU machine before multi-device training: ``python3 benchmarks/device/nccl_check.py``.
"""

import jax
import jax.numpy as jnp


def main() -> None:
    """psum and all_gather over the local devices; print the result."""
    n = jax.local_device_count()
    x = jnp.arange(n, dtype=jnp.float32)
    total = jax.pmap(lambda v: jax.lax.psum(v, "i"), axis_name="i")(x)
    gathered = jax.pmap(lambda v: jax.lax.all_gather(v, "i"), axis_name="i")(x)
    assert float(total[0]) == n * (n - 1) / 2, total
    assert gathered.shape == (n, n), gathered.shape
    print(f"ok: {n} devices {jax.devices()}, psum {total.tolist()}", flush=True)


if __name__ == "__main__":
    main()

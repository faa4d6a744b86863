"""Env-step scaling over GPUs with ``jit`` + ``NamedSharding`` (the path that compiles where pmap crashes).

    python3 benchmarks/device/sharded_env_scaling.py [ENVS_PER_DEVICE] [CONFIG]

For k = 1, 2, 4, ... local devices: the training env step (``AutoResetEnv``: physics, reward,
termination, auto-reset, curriculum over the global batch) under ``lax.scan`` with random actions,
the batch sharded over the k devices along its env axis; prints env-steps/s and efficiency.
"""

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

from hsa_mjx.env import HSAEnv
from hsa_mjx.training_env import AutoResetEnv
from train import config as tcfg

STEPS, REPEATS = 16, 3


def measure(batch_env: AutoResetEnv, devices: list, per_device: int) -> tuple[float, float]:
    """(env-steps/s, compile s) of the sharded env loop over ``devices``."""
    mesh = Mesh(np.array(devices), ("envs",))
    n = per_device * len(devices)
    keys = jax.device_put(jax.random.split(jax.random.PRNGKey(0), n), NamedSharding(mesh, P("envs")))
    state = jax.jit(batch_env.reset)(keys)
    # every leaf with the env axis first is split over the devices, the rest (curriculum) replicated
    spec = jax.tree.map(lambda x: NamedSharding(mesh, P("envs") if x.ndim and x.shape[0] == n else P()), state)
    state = jax.device_put(state, spec)

    def loop(state, key):
        def body(s, k):
            actions = jax.random.uniform(k, (n, batch_env.action_size), minval=-1.0, maxval=1.0)
            return batch_env.step(s, actions), None
        return jax.lax.scan(body, state, jax.random.split(key, STEPS))[0]

    t0 = time.time()
    run = jax.jit(loop, donate_argnums=0, in_shardings=(spec, None), out_shardings=spec)
    run = run.lower(state, jax.random.PRNGKey(1)).compile()
    compile_s = time.time() - t0
    state = jax.block_until_ready(run(state, jax.random.PRNGKey(2)))
    times = []
    for r in range(REPEATS):
        t0 = time.time()
        state = jax.block_until_ready(run(state, jax.random.PRNGKey(3 + r)))
        times.append(time.time() - t0)
    return n * STEPS / float(np.median(times)), compile_s


def main() -> None:
    """Measure every power-of-two device count."""
    per_device = int(sys.argv[1]) if len(sys.argv) > 1 else 8192
    config = tcfg.load(sys.argv[2] if len(sys.argv) > 2 else "configs/train_flat.yaml")
    batch_env = AutoResetEnv(HSAEnv(config.env), config.curriculum)
    devices, base, k = jax.local_devices(), None, 1
    while k <= len(devices):
        rate, compile_s = measure(batch_env, devices[:k], per_device)
        base = base or rate
        print(f"{k} device(s), {per_device * k:,} envs: {rate:,.0f} env-steps/s, speed-up {rate / base:.2f}, "
              f"efficiency {100 * rate / base / k:.0f} %, compile {compile_s:.1f} s", flush=True)
        k *= 2


if __name__ == "__main__":
    main()

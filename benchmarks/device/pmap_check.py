"""Locate a multi-GPU compile crash: compile pieces of the env over all local devices, one per call.

    python3 benchmarks/device/pmap_check.py PIECE     (PIECE: forward | env_reset | auto_reset |
                                                       auto_step | jit_sharded_reset)
Exit 0 and 'ok PIECE' when the piece compiled and ran; a crash shows as the process's exit status.
"""

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
from mujoco import mjx

from hsa_mjx.env import HSAEnv
from hsa_mjx.training_env import AutoResetEnv
from train import config as tcfg

PER_DEVICE = 4


def main(piece: str) -> None:
    """Compile and run one piece over every local device."""
    config = tcfg.load("configs/train_flat.yaml")
    env = HSAEnv(config.env)
    n = jax.local_device_count()
    keys = jax.random.split(jax.random.PRNGKey(0), n * PER_DEVICE).reshape(n, PER_DEVICE, -1)
    t0 = time.time()
    if piece == "forward":
        model = env.robot.mjx_model
        data = jax.tree.map(lambda x: np.stack([np.asarray(x)] * n), mjx.make_data(model))
        out = jax.pmap(lambda d: mjx.forward(model, d))(data).qpos
    elif piece == "env_reset":
        out = jax.pmap(jax.vmap(env.reset))(keys).obs
    elif piece in ("auto_reset", "auto_step"):
        batch = AutoResetEnv(env, config.curriculum, axis_name="d")
        state = jax.pmap(batch.reset, axis_name="d")(keys)
        out = state.env.obs
        if piece == "auto_step":
            actions = jnp.zeros((n, PER_DEVICE, env.action_size))
            out = jax.pmap(batch.step, axis_name="d")(state, actions).env.obs
    elif piece == "jit_sharded_reset":
        mesh = Mesh(np.array(jax.local_devices()), ("d",))
        flat = jax.device_put(keys.reshape(n * PER_DEVICE, -1), NamedSharding(mesh, P("d")))
        out = jax.jit(jax.vmap(env.reset))(flat).obs
    else:
        raise ValueError(f"unknown piece {piece!r}")
    jax.block_until_ready(out)
    print(f"ok {piece}: {n} devices, {time.time() - t0:.1f} s, finite {bool(jnp.all(jnp.isfinite(out)))}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1])

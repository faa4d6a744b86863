"""Batched rollout of the env with random actions: a smoke run and a quick speed reading.

    python -m hsa_mjx.rollout --config configs/flat.yaml --envs 8 --steps 50
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import hsa_mjx


def run(config: str, envs: int, steps: int, seed: int) -> dict[str, float]:
    """Roll out ``envs`` envs for ``steps`` random steps; return summary numbers."""
    env = hsa_mjx.make_env(config)
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    key, act_key = jax.random.split(jax.random.PRNGKey(seed))
    state = reset(jax.random.split(key, envs))
    start = time.perf_counter()
    state = step(state, jnp.zeros((envs, env.action_size)))
    jax.block_until_ready(state.obs)
    compile_s = time.perf_counter() - start
    total_reward = np.zeros(envs)
    dones = 0
    start = time.perf_counter()
    for k in jax.random.split(act_key, steps):
        state = step(state, jax.random.uniform(k, (envs, env.action_size), minval=-1.0, maxval=1.0))
        total_reward += np.asarray(state.reward)
        dones += int(np.asarray(state.done).sum())
    elapsed = time.perf_counter() - start
    return {"envs": envs, "steps": steps, "compile_s": compile_s, "env_steps_per_s": envs * steps / elapsed,
            "mean_return": float(total_reward.mean()), "episodes_ended": dones,
            "all_finite": bool(np.all(np.isfinite(np.asarray(state.obs))))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="flat", help="preset name or YAML path")
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    summary = run(args.config, args.envs, args.steps, args.seed)
    print(f"backend {jax.default_backend()}: " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                                           for k, v in summary.items()))


if __name__ == "__main__":
    main()

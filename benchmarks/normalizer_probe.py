"""Why a fresh run's first PPO updates see huge value losses: observation statistics from the first unroll.

``python -m benchmarks.normalizer_probe [--config configs/train_corridor.yaml] [--envs 32]``
resets a batch of envs (every env starts in the same pose), steps them with random actions in
[-1, 1], takes the per-dimension mean and std of the first ``--unroll`` steps (what the running
statistics hold after the first PPO iteration of a fresh run) and prints, for the dimensions that
move most, how many of those stds the observations have moved ``--later`` steps on. Values in the
hundreds reach the networks unless ``ppo.observation_clip`` clips them (docs/training.md, session 7).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

from benchmarks.run_info import write_table_result
from hsa_mjx.env import HSAEnv
from hsa_mjx.observation import observation_labels
from train import config as tcfg

STD_FLOOR = 1e-6  # the running statistics' own floor (brax running_statistics.update std_min_value)


def random_rollout(env: HSAEnv, envs: int, steps: int, seed: int) -> np.ndarray:
    """Observations (steps, envs, size) under uniform random actions from a fresh reset."""
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    state = reset(jax.random.split(jax.random.PRNGKey(seed), envs))
    key, out = jax.random.PRNGKey(seed + 1), []
    for _ in range(steps):
        key, k_act = jax.random.split(key)
        state = step(state, jax.random.uniform(k_act, (envs, env.action_size), minval=-1.0, maxval=1.0))
        out.append(np.asarray(state.obs))
    return np.stack(out)


def main(argv: list[str] | None = None) -> None:
    """Print and write the dimensions that leave their first-unroll statistics furthest."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.normalizer_probe", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="configs/train_corridor.yaml")
    p.add_argument("--envs", type=int, default=32)
    p.add_argument("--unroll", type=int, default=20, help="steps in the first statistics (ppo.unroll_length)")
    p.add_argument("--later", type=int, default=100, help="steps after which to measure the drift")
    p.add_argument("--rows", type=int, default=8)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/normalizer_probe_cpu"))
    args = p.parse_args(argv)
    tic = time.perf_counter()
    config = tcfg.load(args.config)
    obs = random_rollout(HSAEnv(config.env), args.envs, args.later + args.unroll, seed=0)
    first = obs[:args.unroll].reshape(-1, obs.shape[-1])
    mean, std = first.mean(0), np.maximum(first.std(0), STD_FLOOR)
    drift = np.abs((obs[args.later:] - mean) / std).max(axis=(0, 1))
    order = np.argsort(-drift)[:args.rows]
    rows = [{"slot": int(i), "name": observation_labels(config.env.observation)[i], "first_unroll_std": float(std[i]),
             "max_normalised_later": float(drift[i])} for i in order]
    table = (f"{args.config}, {args.envs} envs, random actions: std over the first {args.unroll} steps and the largest "
             f"|normalised value| at steps {args.later}-{args.later + args.unroll}\n\n"
             "| slot | observation | first-unroll std | max abs normalised later |\n|---|---|---|---|\n"
             + "\n".join(f"| {r['slot']} | {r['name']} | {r['first_unroll_std']:.3g} | {r['max_normalised_later']:.3g} |"
                         for r in rows))
    write_table_result(args.out, table, rows, tic)


if __name__ == "__main__":
    main()

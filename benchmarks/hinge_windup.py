"""How far a long episode's hinge angles drift outside what the policy's normaliser has seen.

    python -m benchmarks.hinge_windup RUN_DIR [--steps 8000] [--every 1000] [--out FILE.md]

Plays RUN_DIR's latest policy (its mean action) for ``--steps`` env steps from the origin in the
run's own env (evaluation settings, ``train.evaluate.evaluation_env_config``) and reports, every
``--every`` steps, the spiral checkpoint index, the eight actuated hinge angles (rad) and the
largest of the observed hinge values in units of the observation normaliser (|value - mean| / std;
the raw angles, or their wrapped or sin/cos form under ``observation.hinge_angles``). With incremental
servo targets over a +-3141.5 rad range the hinges wind up without bound, so an episode longer
than any the batch trained through shows the policy angles it never saw (docs/training.md,
session 13).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from benchmarks.run_info import print_table
from hsa_mjx import observation
from hsa_mjx.env import HSAEnv
from train.evaluate import evaluation_env_config, load_policy, load_training_state


def windup(run_dir: Path, steps: int, every: int) -> list[dict]:
    """Rows of (step, checkpoint index, hinge angles, largest normalised |angle|) every ``every`` steps."""
    config, _, policy, path, _ = load_policy(run_dir)
    env = HSAEnv(evaluation_env_config(config.env))
    _, ts = load_training_state(config, path, env.observation_size, env.action_size)
    labels = observation.observation_labels(config.env.observation)  # raw, wrapped or sin/cos slots
    columns = [i for i, name in enumerate(labels) if name.startswith(("hinge_angle_", "hinge_sin_", "hinge_cos_"))]
    mean, std = (np.asarray(v)[columns] for v in (ts.normalizer.mean, ts.normalizer.std))
    step = jax.jit(lambda s, k: env.step(s, policy(s.obs, k)[0]))
    state, rows = jax.jit(env.reset)(jax.random.PRNGKey(0)), []
    for t in range(1, steps + 1):
        state = step(state, jax.random.PRNGKey(t))
        if t % every == 0 or float(state.done):
            angles = np.asarray(observation.joint_positions(state.pipeline_state.physics, env.index))
            rows.append({"step": t, "index": int(state.metrics["checkpoint_index"]), "angles": angles,
                         "max_z": float(np.max(np.abs(np.asarray(state.obs)[columns] - mean) / std)),
                         "done": float(state.done)})
            if float(state.done):
                break
    return rows


def markdown(rows: list[dict], title: str) -> str:
    """The rows as a markdown table."""
    lines = [f"# {title}", "", "| step | checkpoint index | hinge angles (rad) | max normalised abs angle | done |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['step']} | {r['index']} | {' '.join(f'{a:.0f}' for a in r['angles'])} | {r['max_z']:.1f} "
              f"| {r['done']:.0f} |" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """CLI entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--steps", type=int, default=8000)
    parser.add_argument("--every", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.every < 1:
        raise ValueError(f"--steps and --every must be >= 1, got {args.steps} and {args.every}")
    rows = windup(args.run_dir, args.steps, args.every)
    return print_table(markdown(rows, f"{args.run_dir}: mean action from the origin, {args.steps} steps"), args.out)


if __name__ == "__main__":
    raise SystemExit(main())

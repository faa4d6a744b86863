"""Does a trained policy's gait carry over to another task? Its deterministic rollouts in another env config.

``python -m benchmarks.transfer_probe RUN_DIR --config configs/train_turn.yaml [--set key=value ...]
[--episodes 3] [--steps 1000] [--start-checkpoint K] [--out FILE.md]``

Loads RUN_DIR's latest checkpoint (its observation layout must fit the config's), plays its mean
action for ``--steps`` env steps in the env of ``--config`` (with ``--set`` overrides) from the
resets of seeds 0..episodes-1, and reports per episode the steps played, the goal, the start and
final distance, the spiral checkpoints collected (the current checkpoint's index), the
displacement and how large the policy's action means were (the median over steps of the mean
|pre-tanh loc| over the 8 actions: a gait swings them, a stalled policy keeps them near 0 or at
a constant bias). Session 10 used it to ask why the corridor's policy does not turn
(docs/training.md). ``--start-checkpoint K`` (spiral goals) starts every episode on checkpoint
K - 1 facing checkpoint K, as ``goal.track_starts`` would (``HSAEnv.reset_at_checkpoint``), to
probe one stretch of the track.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from benchmarks.run_info import print_table
from hsa_mjx.env import HSAEnv
from train import config as tcfg
from train.evaluate import evaluation_env_config, load_policy, load_training_state

COLUMNS = ("seed", "steps", "goal_x", "goal_y", "start_distance", "final_distance", "progress_m", "checkpoints",
           "dx", "dy", "median_abs_loc", "loc_swing")


class Probe:
    """A run's policy (mean action) and its pre-tanh action means, with ``env``'s jitted reset and step."""

    def __init__(self, run_dir: Path, env: HSAEnv, start_checkpoint: int = 0):
        config, _, self.policy, path, _ = load_policy(run_dir)
        networks, ts = load_training_state(config, path, env.observation_size, env.action_size)
        self.loc = jax.jit(lambda obs: networks.policy_network.apply(ts.normalizer, ts.params.policy, obs)[:env.action_size])
        reset = (lambda key: env.reset_at_checkpoint(key, start_checkpoint)) if start_checkpoint else env.reset
        self.env, self.reset, self.step = env, jax.jit(reset), jax.jit(env.step)


def probe(p: Probe, seed: int, steps: int) -> dict[str, float]:
    """One deterministic episode (cut at ``steps`` or its end): distances, displacement, action-mean size."""
    env, policy, loc_fn, step = p.env, p.policy, p.loc, p.step
    state = p.reset(jax.random.PRNGKey(seed))
    start_xy = np.asarray(state.pipeline_state.physics.xpos[env.index.block_body, :2]).mean(0)
    start_distance = float(state.metrics["distance_to_goal"])
    locs, played = [], 0
    for t in range(steps):
        played = t + 1
        locs.append(np.asarray(loc_fn(state.obs)))
        action, _ = policy(state.obs, jax.random.PRNGKey(t))
        state = step(state, action)
        if float(state.done):
            break
    xy = np.asarray(state.pipeline_state.physics.xpos[env.index.block_body, :2]).mean(0)
    goal = np.asarray(state.pipeline_state.task.goal_xy)
    locs = np.stack(locs)
    final = float(state.metrics["distance_to_goal"])
    return {"seed": seed, "steps": played, "checkpoints": float(state.metrics["checkpoint_index"]), "goal_x": goal[0], "goal_y": goal[1], "start_distance": start_distance,
            "final_distance": final, "progress_m": start_distance - final, "dx": xy[0] - start_xy[0],
            "dy": xy[1] - start_xy[1], "median_abs_loc": float(np.median(np.abs(locs).mean(1))),
            "loc_swing": float(np.mean(np.std(locs, axis=0)))}


def markdown(rows: list[dict[str, float]], title: str) -> str:
    """A markdown table of the probe rows."""
    lines = [f"# {title}", "", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(f"{r[c]:.3f}" if c not in ("seed", "steps") else str(r[c]) for c in COLUMNS) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """CLI entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--config", required=True, help="a training YAML whose env section is used")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--start-checkpoint", type=int, default=0, metavar="K",
                        help="spiral: start on checkpoint K - 1 facing K (default 0: the origin)")
    parser.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    args = parser.parse_args(argv)
    env = HSAEnv(evaluation_env_config(tcfg.load(args.config, args.overrides).env))
    runner = Probe(args.run_dir, env, args.start_checkpoint)
    rows = [probe(runner, seed, args.steps) for seed in range(args.episodes)]
    start = f", from checkpoint {args.start_checkpoint}" if args.start_checkpoint else ""
    title = f"{args.run_dir} in {args.config} {' '.join(args.overrides)} ({args.steps} steps{start})"
    return print_table(markdown(rows, title), args.out)


if __name__ == "__main__":
    raise SystemExit(main())

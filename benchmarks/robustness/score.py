"""How a policy fares on models that differ from the one it trained on:
``python -m benchmarks.robustness.score POLICY``.

``--grid nominal`` (72 cells within the randomised training span) or ``--grid stress`` (24 cells that
go past it: each factor alone at both ends of its stress range, and four corners), described in
``benchmarks/robustness/grids.py``. Every cell plays ``--episodes`` episodes from the same starts and
goals (the policy's training goal range) with the policy's mean action, for at most ``--steps`` steps.
A cell reports its success rate with a 95 % Wilson interval, its mean net progress towards the goal
and how its failed episodes ended; the summary gives the lowest success, the lowest lower bound and
the cells whose upper bound is below 90 %. Episodes end on simulator health (non-finite state, a
block out of its height band, the velocity limit), on leaving the arena and at the goal; the
original's joint-acceleration rule (``qacc_limit``) only with ``--qacc-rule on``.

``--sim-to-sim``: the same cells (those without pushes) are played again on C MuJoCo through the
deployment loop (``hsa_mjx.deploy``: the policy sees only sensor readings), with the same goals, and
each cell's gap to the MJX figure is reported. Results: ``robustness_<tag>.json``, a table (``.md``)
and a heat map (``.png``) under ``--out-dir``.

One compiled rollout serves every cell of a noise setting: the env randomises the factors over the
cells' span and each episode's draws are then set to its cell's values (``hsa_mjx.task.randomization``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.robustness import grids, report
from benchmarks.run_info import run_info
from benchmarks.stats import wilson_interval
from hsa_mjx.config import BACKENDS
from hsa_mjx.deploy import policy_file
from hsa_mjx.deploy.loop import latency_steps
from hsa_mjx.randomization_config import FOOT_KEYS, RandomizationConfig
from hsa_mjx.robots import profile_servo
from hsa_mjx.sim.backend import for_one_env
from hsa_mjx.task.randomization import SERVO_FIGURES, PhysicsScales
from train.config import from_dict
from train.episodes.policy_sources import default_goal_range, load_shipped_policy
from train.episodes.rollout import episode_success, rollout, summarize
from train.run.folder import portable

RESULTS = Path(__file__).resolve().parents[1] / "results" / "robustness"
RESOLVING_EPISODES = report.RESOLVING_EPISODES


def env_overrides(
    group: list[dict], dt: float, qacc_rule: bool, figures: list[tuple[float, ...]] | None = None
) -> tuple[str, ...]:
    """``env.KEY=VALUE`` overrides: every randomisation off but the cells' span (so that a policy trained
    with randomisation is scored on each cell's model alone), the group's noise, the qacc rule.
    ``figures``: a DC-motor policy's servo figure scales per cell (``grids.dc_motor_cell``)."""
    ranges: dict[str, Any] = dataclasses.asdict(RandomizationConfig())
    values = [v for row in figures or () for v in row]
    if any(v != 1.0 for v in values):  # the env compiled with per-env servo figures
        ranges["servo_figures"] = [min(values), max(values)]
    for name in grids.SCALES:
        values = [c[name] for c in group]
        if any(v != 1.0 for v in values):
            ranges[name] = [min(values), max(values)]
    limits = [c["servo_torque_limit"] for c in group if c["servo_torque_limit"] is not None]
    if limits:
        ranges["servo_force_limit"] = [min(limits), max(limits)]
    for name in FOOT_KEYS:  # the feet's fields compiled per env where a cell scales a foot
        values = [v for c in group for v in c[name]]
        if any(v != 1.0 for v in values):
            ranges[name] = [min(values), max(values)]
    ranges["latency_steps"] = [0, max(latency_steps(c["latency_ms"], dt) for c in group)]
    if any(c["pushes"] for c in group):
        ranges["push_interval_s"], ranges["push_speed"] = list(grids.PUSH_INTERVAL_S), grids.PUSH_SPEED
    classes = servo_classes(group)
    if classes:  # the group's profiles' servos, drawn per cell
        ranges["robots"] = list(classes)
    out = [f"env.randomization.{k}={json.dumps(list(v) if isinstance(v, tuple) else v)}" for k, v in ranges.items()]
    own = dataclasses.asdict(profile_servo(classes[0])) if classes else {}  # the nominal: the first profile's
    out += [f"env.servo.{k}={json.dumps(v)}" for k, v in own.items()]
    out += [f"env.observation.noise.{k}={v if group[0]['noise'] else 0}" for k, v in grids.NOISE.items()]
    out.append(f"env.termination.qacc_termination={'true' if qacc_rule else 'false'}")  # whatever it trained with
    return tuple(out)


def servo_classes(group: list[dict]) -> tuple[str, ...]:
    """The robot profiles whose servos a group's cells drive, in order of first use (empty: the policy's own)."""
    return tuple(dict.fromkeys(c["servo"] for c in group if c["servo"] is not None))


def cell_randomization(
    group: list[dict], episodes: int, dt: float, figures: list[tuple[float, ...]] | None = None
) -> dict[str, Any]:
    """Each episode's physical scales, latency and pushes, (cells x episodes,) leading axis (``figures``:
    a DC-motor policy's servo figure scales per cell)."""

    classes = servo_classes(group)
    group = [{**c, "robot": classes.index(c["servo"]) if c["servo"] else 0} for c in group]

    def per_episode(name: str, dtype=jnp.float32) -> jnp.ndarray:
        return jnp.repeat(jnp.asarray([c[name] for c in group], dtype), episodes)

    limits = [np.inf if c["servo_torque_limit"] is None else c["servo_torque_limit"] for c in group]
    physics = PhysicsScales(
        friction=per_episode("friction"),
        block_mass=jnp.repeat(per_episode("block_mass")[:, None], 2, axis=1),
        hsa_stiffness=per_episode("hsa_stiffness"),
        hsa_damping=per_episode("hsa_damping"),
        servo_gain=per_episode("servo_gain"),
        servo_force_limit=jnp.repeat(jnp.asarray(limits, jnp.float32), episodes),
        foot_friction=jnp.repeat(jnp.asarray([c["foot_friction"] for c in group], jnp.float32), episodes, axis=0),
        foot_anisotropy=jnp.repeat(jnp.asarray([c["foot_anisotropy"] for c in group], jnp.float32), episodes, axis=0),
        robot=per_episode("robot", jnp.int32),
        servo_figures=jnp.repeat(
            jnp.asarray(figures or [(1.0,) * len(SERVO_FIGURES)] * len(group), jnp.float32), episodes, axis=0
        ),
    )
    latency = jnp.repeat(jnp.asarray([latency_steps(c["latency_ms"], dt) for c in group], jnp.int32), episodes)
    return {"physics": physics, "latency": latency, "pushes": per_episode("pushes", bool)}


def score(successes: int, episodes: int) -> dict[str, Any]:
    """A cell's success count, rate and 95 % Wilson interval."""
    low, high = wilson_interval(successes, episodes)
    return {"successes": successes, "episodes": episodes, "success_rate": successes / episodes, "ci95": [low, high]}


def run_group(directory: Path, group: list[dict], args: argparse.Namespace, backend: str) -> list[dict[str, Any]]:
    """The cells of one compiled env (one noise setting and servo model) in one rollout: a result row per
    cell (with its episodes' goals and outcomes)."""
    own = from_dict(policy_file.load_policy(directory).meta["config"]).env
    dt, figures, played = own.dt, None, group
    if own.servo.model != "spring":  # the gain and torque cells as the policy's own motors' figures
        played, figures = map(list, zip(*(grids.dc_motor_cell(c, own.servo.stall_torque) for c in group)))
    overrides = env_overrides(played, dt, args.qacc_rule == "on", figures)
    episodes = args.episodes
    config, env, policy, _ = load_shipped_policy(directory, backend, len(group) * episodes, overrides)
    steps = args.steps or config.env.termination.max_episode_steps
    keys = jnp.tile(jax.random.split(jax.random.PRNGKey(args.seed), episodes), (len(group), 1))  # same episodes
    goal_range = jnp.asarray(default_goal_range(config), jnp.float32)
    randomization = cell_randomization(played, episodes, env.dt, figures)
    traces = jax.device_get(rollout(env, policy, keys, goal_range, steps, randomization=randomization))
    rows = []
    for i, c in enumerate(group):
        part = {k: np.asarray(v)[i * episodes : (i + 1) * episodes] for k, v in traces.items()}
        summary = summarize(part, env.dt)
        rows.append(
            {
                **c,
                "label": grids.label(c),
                **score(int(round(summary["success_rate"] * episodes)), episodes),
                "mean_progress_m": summary["mean_progress_m"],
                "mean_final_distance": summary["mean_final_distance"],
                "failures": failures(summary),
                "goals": part["goal"][:, 0].tolist(),
                "reached": episode_success(part).tolist(),  # each episode's outcome, for the paired sim-to-sim gap
            }
        )
    return rows


def failures(summary: dict[str, Any]) -> dict[str, float]:
    """How the failed episodes ended: each termination reason's share, ``time_out`` (the env's episode
    limit) and ``not_finished`` (``--steps`` below that limit)."""
    ends = {
        k.removeprefix("termination/"): v
        for k, v in summary.items()
        if k.startswith("termination/") and k != "termination/goal_reached"
    }
    timing = {"time_out": summary["time_out"], "not_finished": summary["not_finished"]}
    return {k: v for k, v in {**ends, **timing}.items() if v > 0}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line's arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.robustness.score",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("policy", metavar="NAME_OR_DIR", help="a shipped policy's name or a policy directory")
    parser.add_argument("--grid", default="nominal", help=f"the cells: {' or '.join(grids.GRIDS)} (default nominal)")
    parser.add_argument(
        "--episodes", type=int, default=None, help=f"episodes per cell (default {RESOLVING_EPISODES}; 8 on C MuJoCo)"
    )
    parser.add_argument("--steps", type=int, default=None, help="max steps per episode (default: the env's limit)")
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="auto",
        help="physics: auto (C MuJoCo on a CPU, MJX on a GPU), c, jax or warp",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--where",
        action="append",
        default=[],
        metavar="FACTOR=VALUE",
        help="only the matching cells (repeatable: every factor given, any of a factor's values)",
    )
    parser.add_argument(
        "--part",
        default=None,
        metavar="K/N",
        help="every N-th chosen cell from the K-th: a long grid in parts (joined by benchmarks.robustness.merge)",
    )
    parser.add_argument("--qacc-rule", choices=("off", "on"), default="off", help="end episodes on qacc_limit too")
    parser.add_argument("--sim-to-sim", action="store_true", help="also play the cells on C MuJoCo's deployment loop")
    parser.add_argument("--workers", type=int, default=None, help="--sim-to-sim processes (default: all CPUs)")
    parser.add_argument("--tag", default=None, help="file name tag (default: the policy folder's name and the grid)")
    parser.add_argument("--out-dir", default=str(RESULTS))
    return parser.parse_args(argv)


def resolve(args: argparse.Namespace) -> tuple[Path, str, list[dict]]:
    """(policy directory, backend, cells) of the command line; ValueError or FileNotFoundError before any compile."""
    directory = policy_file.locate(args.policy)
    backend = for_one_env(args.backend)
    if args.episodes is None:
        args.episodes = 8 if backend == "c" else RESOLVING_EPISODES
    if args.episodes < 1 or (args.steps is not None and args.steps < 1):
        raise ValueError(f"--episodes and --steps must be >= 1, got {args.episodes} and {args.steps}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    return directory, backend, grids.part(grids.select(grids.grid(args.grid), args.where), args.part)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.robustness.score``."""
    args = parse_args(argv)
    try:
        directory, backend, chosen = resolve(args)
        rows: list = [None] * len(chosen)  # in the grid's order, whichever rollout played them
        for group in grids.rollout_groups(chosen):
            for c, row in zip(group, run_group(directory, group, args, backend)):
                rows[chosen.index(c)] = row
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    sim_rows = []
    if args.sim_to_sim:
        from benchmarks.robustness.sim_to_sim import play_cells

        sim_rows = play_cells(directory, rows, args.steps, args.qacc_rule == "on", args.workers)
    tag = args.tag or f"{directory.resolve().name}_{args.grid}"
    result = {
        **run_info(),
        "policy": portable(directory),  # no machine's absolute path
        "grid": args.grid,
        "episodes_per_cell": args.episodes,
        "seed": args.seed,
        "max_steps": args.steps,
        "physics_backend": backend,
        "qacc_rule": args.qacc_rule,
        "where": args.where,
        "part": args.part,
        "noise_on": grids.NOISE,
        "pushes_on": {"interval_s": list(grids.PUSH_INTERVAL_S), "speed_m_per_s": grids.PUSH_SPEED},
        **report.summary(rows, RESOLVING_EPISODES),
        "cells": rows,
        "sim_to_sim": sim_rows,
    }
    for line in report.write(result, Path(args.out_dir), tag):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How fast each robot profile crawls, and the flat task scaled to that speed.

    python -m benchmarks.robots.speed [--robots all] [--gaits extend_contract] [--seconds 10]
        [--policy-eval NAME=EVAL.json ...] [--out benchmarks/results/robots/speed.json]

Two speeds per profile (``robots/``):
- the original's open-loop gaits (``benchmarks.fidelity.gaits``) through the profile's control law and servos, on
  C MuJoCo's flat floor: the straight-line distance the blocks' midpoint moves over ``--seconds``;
- its own policy's, read from a ``python -m train.evaluate`` file (``mean_speed_m_per_s``: displacement
  over episode time, every episode), given with ``--policy-eval``.

The task rule (:func:`scaled_task`): the farthest goal is as many seconds of travel at the profile's
policy speed as the original's farthest goal (4.5 m) is at the original's policy speed (the reference
file below), the nearest goal at least ``NEAREST_M``, the episode at least ``EPISODE_FACTOR`` times
the farthest goal's travel time. The ``configs/train_flat_<profile>.yaml`` headers cite the result.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import platform
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fidelity.gaits import GAITS, gait_actions, gait_layout

REFERENCE_EVAL = "benchmarks/results/training/flat_warp/eval_deterministic_cpu.json"  # the original's policy
REFERENCE_FARTHEST_M = 4.5  # the original task's farthest goal
NEAREST_M = 0.5
EPISODE_FACTOR = 3.0
DEFAULT_OUT = "benchmarks/results/robots/speed.json"


@dataclasses.dataclass(frozen=True)
class ScaledTask:
    """A flat task scaled to a robot's speed: goal distances (m) and the shortest episode (s) allowed."""

    nearest_m: float
    farthest_m: float
    min_episode_s: float


def scaled_task(speed: float, reference_speed: float) -> ScaledTask:
    """The rule: the farthest goal at the reference's travel time to 4.5 m, at least ``NEAREST_M``; the
    episode at least ``EPISODE_FACTOR`` times the farthest goal's travel time."""
    if speed <= 0 or reference_speed <= 0:
        raise ValueError(f"speeds must be > 0, got {speed} and reference {reference_speed}")
    farthest = max(NEAREST_M, speed * REFERENCE_FARTHEST_M / reference_speed)
    return ScaledTask(NEAREST_M, round(farthest, 2), round(EPISODE_FACTOR * farthest / speed, 1))


def gait_speed(robot: str, gait: str, seconds: float) -> float:
    """The gait's straight-line speed (m/s) on the profile's robot: C MuJoCo, flat floor, no noise."""
    from hsa_mjx.config import get_preset, with_overrides
    from hsa_mjx.deploy.loop import SimulatedRobot, load_model
    from hsa_mjx.task.control import next_targets

    config = with_overrides(get_preset("flat"), robot=robot)
    mj_model, index = load_model(config)
    sim = SimulatedRobot(mj_model, index, config)
    steps = int(round(seconds / config.dt))
    actions = gait_actions(gait, gait_layout(mj_model), steps, config.dt)
    control, targets = config.control, np.zeros(len(index.servo_ids))
    start = sim.read().block_positions[:, :2].mean(axis=0)
    for action in actions.astype(np.float64):
        targets = next_targets(targets, action, control.max_increment, control.servo_target_limit, xp=np)
        sim.command(targets)
    end = sim.read().block_positions[:, :2].mean(axis=0)
    return float(np.linalg.norm(end - start) / (steps * config.dt))


def policy_speed(path: str | Path) -> dict[str, Any]:
    """The figures of a ``train.evaluate`` file that the rule and the report use."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"evaluation file not found: {path}")
    data = json.loads(path.read_text())
    keys = ("checkpoint", "step", "physics", "episodes", "goal_range", "success_rate", "mean_speed_m_per_s")
    missing = [k for k in ("mean_speed_m_per_s", "success_rate") if k not in data]
    if missing:
        raise ValueError(f"{path}: not a train.evaluate file (missing {missing})")
    return {k: data.get(k) for k in keys}


def _policy_evals(items: list[str], robots: list[str]) -> dict[str, dict[str, Any]]:
    evals = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or name not in robots:
            raise ValueError(f"--policy-eval takes NAME=EVAL.json with NAME one of {robots}, got {item!r}")
        evals[name] = policy_speed(path)
    return evals


def measure(robots: list[str], gaits: list[str], seconds: float, evals: dict[str, dict]) -> dict[str, Any]:
    """Every profile's gait speeds, its policy's speed and its scaled task (None without a policy)."""
    reference = policy_speed(REFERENCE_EVAL)
    rows = []
    for robot in robots:
        row: dict[str, Any] = {"robot": robot, "gaits": {g: gait_speed(robot, g, seconds) for g in gaits}}
        policy = evals.get(robot)
        row["policy"] = policy
        task = scaled_task(policy["mean_speed_m_per_s"], reference["mean_speed_m_per_s"]) if policy else None
        row["task"] = dataclasses.asdict(task) if task else None
        rows.append(row)
        print(f"{robot}: {row}", flush=True)
    return {"reference": reference, "seconds": seconds, "rows": rows}


def markdown(report: dict[str, Any]) -> str:
    """The report as a Markdown page."""
    ref, gaits = report["reference"], list(report["rows"][0]["gaits"])
    lines = [
        f"# Robot speeds and scaled tasks ({report['date']}, {report['host']})",
        "",
        f"`{report['command']}`",
        "",
        f"Rule: farthest goal = policy speed x {REFERENCE_FARTHEST_M} m / {ref['mean_speed_m_per_s']:.3f} m/s "
        f"(the original's policy, `{REFERENCE_EVAL}`), at least {NEAREST_M} m; episode >= {EPISODE_FACTOR:g} x "
        f"the farthest goal's travel time. Gaits: {report['seconds']:g} s on C MuJoCo's flat floor.",
        "",
        "| robot | " + " | ".join(f"{g} m/s" for g in gaits) + " | policy m/s | policy success | policy step | "
        "policy physics | goals m | episode >= s |",
        "|---|" + "---|" * (len(gaits) + 6),
    ]
    for row in report["rows"]:
        p, t = row["policy"], row["task"]
        cells = [f"{row['gaits'][g]:.3f}" for g in gaits]
        cells += (
            [f"{p['mean_speed_m_per_s']:.4f}", f"{p['success_rate']:.1%}", f"{p['step']:,}", str(p["physics"])]
            if p
            else ["-"] * 4
        )
        cells += [f"{t['nearest_m']}-{t['farthest_m']}", f"{t['min_episode_s']}"] if t else ["-"] * 2
        lines.append(f"| {row['robot']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.robots.speed``."""
    from hsa_mjx.robots import profile_names

    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.robots.speed",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--robots", default="all", help="profile names, comma-separated, or all")
    parser.add_argument("--gaits", default="extend_contract", help=f"comma-separated, of {sorted(GAITS)}")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--policy-eval", action="append", default=[], metavar="NAME=EVAL.json")
    parser.add_argument("--out", default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    robots = profile_names() if args.robots == "all" else args.robots.split(",")
    try:
        unknown = sorted(set(robots) - set(profile_names())) + sorted(set(args.gaits.split(",")) - set(GAITS))
        if unknown:
            raise ValueError(f"unknown robot(s) or gait(s) {unknown}; robots {profile_names()}, gaits {sorted(GAITS)}")
        evals = _policy_evals(args.policy_eval, robots)
        report = measure(robots, args.gaits.split(","), args.seconds, evals)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    report |= {
        "date": datetime.date.today().isoformat(),
        "host": f"{os.cpu_count()}-core {platform.machine()} CPU",
        "command": "python -m benchmarks.robots.speed " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    out.with_suffix(".md").write_text(markdown(report))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

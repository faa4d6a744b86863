"""Time to a training target, read from the logs of finished runs.

    python -m benchmarks.scaling.time_to_target RUN_DIR [RUN_DIR ...] [--success 0.9 | --at-env-steps N]
        [--evaluate-episodes N] [--out-dir DIR --tag NAME]

For each run (a folder ``python -m train`` wrote, or a copy under ``benchmarks/results/training/``)
it reads ``config.yaml`` and ``metrics.jsonl`` and reports the first log at which the goal
curriculum has reached its full range (``goal_curriculum.target_range``; a run without the curriculum
counts from its first log) with a logged episode success rate of at least ``--success``: the
training loop's wall-clock to it (``training/walltime``, which includes the first epoch's compile;
a resumed run's calls are added up), the time from the process's launch to it (``training/since_launch``:
the loop's clock and the start-up before it, imports and the env's build; runs logged before that key
show ``-``), the env steps and the PPO iterations to it. Beside it, what the
run had at its last log: wall-clock, env steps, iterations, success, goal range and, on terrain, the
mean terrain level. A target never met is reported as ``null`` with the last log's figures.
``--at-env-steps N`` takes as the target the first log at N env steps or more instead: the step
count at which an evaluation found the target met (a sweep's, ``benchmarks.sweeps.run``), so that the run's
clock to it is read without the logged success rate, which counts the episodes that end (successes
end sooner, and the goal curriculum's range lags the skill). The
first log's wall-clock (the compile and the first epoch) is given too: it depends on the caches
(XLA's and Warp's kernel cache), so runs compare best on the time after it. Each run's start-up parts
(``summary.json``'s ``startup``, ``train.run.startup``: imports, build, first state, reset, the first
update and its compile, and whether the caches were cold) go into its JSON row; the table shows the
first update's time from launch and ``cold caches``.

The logged success rate is the training episodes': read from evaluations instead, the target is the
first of the run's evaluated checkpoints at ``--success`` (its mean action, ``RUN/sweep_checkpoints/``,
``benchmarks.sweeps.checkpoints``: what a sweep with ``evaluate.every_checkpoint`` leaves), with its
training clock and, from the start-up record, its time from launch. ``--evaluate-episodes N`` first
evaluates the checkpoints not yet evaluated, N episodes each over the goal curriculum's full range. Both
learners' runs are read alike (an iteration: PPO's collection, or TD3's one step of every env).

Why PPO iterations: with weak scaling (the one-GPU batch on every GPU) an iteration of k GPUs
takes about the wall-clock of one GPU's and holds k times the samples, so comparing iterations says
whether the larger batch learns more per iteration, which is what decides the time to the target.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml

import hsa_mjx.migrations
from benchmarks.sweeps import checkpoints
from train.run.logger import read_jsonl

SUCCESS = "episode/success_rate"
GOAL = "curriculum/max_distance"
LEVEL = "terrain/mean_level"
WALL = "training/walltime"  # the training loop's clock (the first epoch's compile included)
LAUNCH = "training/since_launch"  # the process's age: the loop's clock and the start-up before it


def read_run(run_dir: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(resolved config, log rows) of a run folder; FileNotFoundError naming what is missing.

    Where the run wrote ``summary.json``, its ``physics_backend`` (the backend ``auto`` resolved to)
    replaces the config's.
    """
    paths = [run_dir / "config.yaml", run_dir / "metrics.jsonl"]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"not a training run folder (missing {missing})")
    config = yaml.safe_load(paths[0].read_text())
    rows = read_jsonl(paths[1])
    if not rows:
        raise ValueError(f"{paths[1]} holds no log rows")
    summary = run_dir / "summary.json"
    if summary.is_file() and "physics_backend" in (resolved := json.loads(summary.read_text())):
        config["env"]["physics"]["backend"] = resolved["physics_backend"]
    return config, rows


def read_startup(run_dir: Path) -> dict[str, Any] | None:
    """The start-up parts of the run's last training call (``summary.json``'s ``startup``: imports, build,
    first state, env reset, first update and its compile, the caches it found), or ``None``."""
    summary = run_dir / "summary.json"
    return json.loads(summary.read_text()).get("startup") if summary.is_file() else None


def cumulative_walltime(rows: list[dict[str, Any]], key: str = WALL) -> list[float | None]:
    """``key`` (``training/walltime``) of each row, with each resumed call's clock added to the calls
    before it; ``None`` for a row without it (``training/since_launch`` of runs older than that key)."""
    total, offset, last = [], 0.0, 0.0
    for row in rows:
        if row.get(key) is None:
            total.append(None)
            continue
        now = float(row[key])
        if now < last:  # a resumed call restarts its clock
            offset += last
        last = now
        total.append(offset + now)
    return total


def iteration_steps(config: dict[str, Any]) -> int:
    """Env steps of one iteration: PPO's (every device's sequences of all minibatches, each ``unroll_length``
    long), or TD3's (one step of every env)."""
    if config["run"].get("learner", "ppo") == "td3":
        return int(config["run"]["num_envs"])
    ppo = config["ppo"]
    return int(ppo["batch_size"]) * int(ppo["num_minibatches"]) * int(ppo["unroll_length"])


def _snapshot(row: dict[str, Any], wall: float, launch: float | None, per_iteration: int) -> dict[str, Any]:
    """The figures of one log row."""
    return {
        "wall_s": round(wall, 1),
        "since_launch_s": None if launch is None else round(launch, 1),
        "env_steps": int(row["step"]),
        "ppo_iterations": int(row["step"]) // per_iteration,
        "success_rate": row.get(SUCCESS),
        "goal_max_m": row.get(GOAL),
        "mean_terrain_level": row.get(LEVEL),
    }


def time_to_target(
    config: dict[str, Any], rows: list[dict[str, Any]], success: float, at_env_steps: int | None = None
) -> dict[str, Any]:
    """The run's figures at the first log meeting the target (``None`` when none does) and at its last
    log. The target: the goal curriculum's full range (where it is on) with a logged success rate of
    ``success``, or, given ``at_env_steps``, the first log at that many env steps."""
    walls, launches = cumulative_walltime(rows), cumulative_walltime(rows, LAUNCH)
    per_iteration = iteration_steps(config)
    curriculum = hsa_mjx.migrations.training_keys(config).get("goal_curriculum", {})  # older runs: "curriculum"
    goal_max = float(curriculum["target_range"][1]) if curriculum.get("enabled") else None
    target = {"goal_max_m": goal_max, "success_rate": success}
    if at_env_steps is not None:
        target = {"env_steps": at_env_steps}
    hit = None
    for row, wall, launch in zip(rows, walls, launches):
        if at_env_steps is not None:
            met = int(row["step"]) >= at_env_steps
        else:
            at_range = goal_max is None or (row.get(GOAL) or 0.0) >= goal_max - 1e-3
            met = at_range and (row.get(SUCCESS) or 0.0) >= success
        if met:
            hit = _snapshot(row, wall, launch, per_iteration)
            break
    run = config["run"]
    return {
        "learner": run.get("learner", "ppo"),
        "num_envs": run["num_envs"],
        "num_devices": run.get("num_devices"),
        "physics_backend": config["env"]["physics"].get("backend"),
        "iteration_env_steps": per_iteration,
        "target": target,
        "first_log_s": round(walls[0], 1),
        "reached": hit,
        "last": _snapshot(rows[-1], walls[-1], launches[-1], per_iteration),
    }


def markdown(results: dict[str, dict[str, Any]]) -> str:
    """One table row per run: time to the target, and the last log."""
    lines = [
        "| run | envs | devices | first update from launch (s) | cold caches | first log (s) | target reached at (s) | "
        "from launch (s) | env steps | iterations | last log (s) | env steps | iterations | success | goal max (m) "
        "| mean terrain level | evaluated target at (training s, from launch s, env steps) |",
        "|" + "---|" * 17,
    ]
    for name, r in results.items():
        hit, last, startup = r["reached"] or {}, r["last"], r.get("startup") or {}
        cells = [
            name,
            f"{r['num_envs']:,}",
            r["num_devices"] or "all local",
            startup.get("first_update_since_launch_s", "-"),
            {True: "yes", False: "no"}.get(startup.get("cold_caches"), "-"),
            r["first_log_s"],
            hit.get("wall_s", "not reached"),
            hit.get("since_launch_s") or "-",
            f"{hit['env_steps']:,}" if hit else "-",
            hit.get("ppo_iterations", "-"),
            last["wall_s"],
            f"{last['env_steps']:,}",
            last["ppo_iterations"],
            _round(last["success_rate"]),
            _round(last["goal_max_m"]),
            _round(last["mean_terrain_level"]),
            _evaluated_cell(r.get("evaluated")),
        ]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


def evaluated_target(run_dir: Path, success: float, startup: dict[str, Any] | None) -> dict[str, Any]:
    """The first evaluated checkpoint at ``success`` (None when none is) and how many were evaluated; its
    time from launch: the start-up before the training loop (one call's) and the training clock."""
    curve = checkpoints.curve(run_dir)
    hit = checkpoints.time_to_target(curve, success)
    if hit and startup and startup.get("first_update_since_launch_s") is not None:
        before = startup["first_update_since_launch_s"] - startup["first_update_s"]
        hit = {**hit, "since_launch_s": round(before + hit["training_s"], 1)}
    return {"success": success, "checkpoints_evaluated": len(curve), "reached": hit}


def _evaluated_cell(evaluated: dict[str, Any] | None) -> str:
    if not evaluated or not evaluated["checkpoints_evaluated"]:
        return "-"
    hit = evaluated["reached"]
    if not hit:
        return f"not reached ({evaluated['checkpoints_evaluated']} checkpoints)"
    return f"{hit['training_s']:.0f}, {hit.get('since_launch_s', '-')}, {hit['env_steps']:,}"


def evaluate_checkpoints(run_dir: Path, episodes: int) -> None:
    """Evaluate the run's checkpoints not yet evaluated (``train.evaluate``, its mean action, ``episodes``
    goals over the goal curriculum's full range), each beside its training clock."""
    config = read_run(run_dir)[0]
    curriculum = hsa_mjx.migrations.training_keys(config).get("goal_curriculum", {})
    goals = curriculum["target_range"] if curriculum.get("enabled") else config["env"]["goal"]["radial_range"]
    base = ["-m", "train.evaluate", str(run_dir), "--out", "", "--episodes", str(episodes), "--seed", "1000"]
    base += ["--goal-range", *(str(g) for g in goals)]
    pending = checkpoints.pending(run_dir)
    for args in checkpoints.commands(base, pending, run_dir):  # one batch of all of them
        subprocess.run([sys.executable, *args], check=True)
    for path in pending:
        checkpoints.write_clock(path, run_dir)


def _round(value: float | None) -> str:
    """Two decimals, or "-" when the run did not log it."""
    return "-" if value is None else f"{value:.2f}"


def run_names(run_dirs: list[str]) -> list[str]:
    """Each run's name in the report: the shortest tail of its path that tells the runs apart (a sweep's
    ``ppo/seed0`` and ``td3/seed0``; a lone run: its folder's name)."""
    parts = [Path(d).resolve().parts for d in run_dirs]
    for depth in range(1, max(len(p) for p in parts) + 1):
        names = ["/".join(p[-depth:]) for p in parts]
        if len(set(names)) == len(names):
            return names
    raise ValueError(f"the same run folder is given twice: {run_dirs}")


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.scaling.time_to_target``."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.scaling.time_to_target",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("run_dirs", nargs="+", help="run folders (config.yaml and metrics.jsonl)")
    parser.add_argument("--success", type=float, default=0.9, help="logged success rate to reach (default 0.9)")
    parser.add_argument(
        "--at-env-steps", type=int, default=None, help="the target is the first log at this many env steps instead"
    )
    parser.add_argument(
        "--evaluate-episodes",
        type=int,
        default=0,
        help="first evaluate each checkpoint not yet evaluated with this many goals (0: read what is there)",
    )
    parser.add_argument("--out-dir", default=None, help="write time_to_target_<tag>.{json,md} here")
    parser.add_argument("--tag", default="runs")
    args = parser.parse_args(argv)
    if not 0.0 < args.success <= 1.0:
        parser.error(f"--success must be in (0, 1], got {args.success}")
    if args.at_env_steps is not None and args.at_env_steps < 1:
        parser.error(f"--at-env-steps must be a positive number of env steps, got {args.at_env_steps}")
    try:
        for d in args.run_dirs if args.evaluate_episodes > 0 else ():
            evaluate_checkpoints(Path(d), args.evaluate_episodes)
        results = {}
        for name, d in zip(run_names(args.run_dirs), args.run_dirs):
            startup = read_startup(Path(d))
            results[name] = {
                **time_to_target(*read_run(Path(d)), args.success, args.at_env_steps),
                "startup": startup,
                "evaluated": evaluated_target(Path(d), args.success, startup),
            }
    except (FileNotFoundError, ValueError, KeyError) as err:
        print(f"error: {err}")
        return 2
    table = markdown(results)
    print(table, end="")
    if args.out_dir:
        out = Path(args.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / f"time_to_target_{args.tag}.json").write_text(json.dumps(results, indent=1))
        (out / f"time_to_target_{args.tag}.md").write_text(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Every checkpoint of a sweep's run evaluated (``evaluate.every_checkpoint: true``): evaluated success
against the training clock, and the time to the target read from those evaluations, not from logs.

With ``budget_s`` the runs train for equal wall-clock (``run.max_training_s``) and, with
``run.checkpoint_every_s`` in the sweep's ``set``, checkpoint at a steady clock; each checkpoint's
evaluation goes to ``RUN/sweep_checkpoints/<checkpoint>/`` beside ``clock.json`` (its env steps and
``training_walltime_s``, from the checkpoint's metadata). A checkpoint never changes, so an evaluation
once written stays valid; keep the checkpoints (``run.keep_checkpoints``) until they are evaluated.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from benchmarks.stats import wilson_interval
from benchmarks.sweeps.grid import read_json
from train.run import checkpoint

FOLDER = "sweep_checkpoints"
RESUMED = (
    "A run of several calls resumed from its newest checkpoint at each: its training clock adds up the calls' "
    "training; an off-policy learner's replay buffer starts empty at each resume and is refilled on that clock."
)


def evaluated(folder: Path) -> dict[str, Any] | None:
    """An evaluation folder's successes, episodes, rate and Wilson interval (terrain: every type and level
    pooled); None when it holds none."""
    flat, terrain = read_json(folder / "eval.json"), read_json(folder / "terrain_eval.json")
    if terrain.get("rows"):
        rows = terrain["rows"]
        successes = int(sum(round(r["success_rate"] * r["episodes"]) for r in rows))
        episodes = int(sum(r["episodes"] for r in rows))
    elif flat:
        episodes = int(flat["episodes"])
        successes = int(round(flat["success_rate"] * episodes))
    else:
        return None
    low, high = wilson_interval(successes, episodes)
    return {"successes": successes, "episodes": episodes, "success_rate": successes / episodes, "ci95": [low, high]}


def pending(run_dir: Path) -> list[Path]:
    """The run's checkpoints with no evaluation yet, oldest first."""
    done = lambda c: evaluated(run_dir / FOLDER / c.name) is not None  # noqa: E731
    return [c for c in checkpoint.list_checkpoints(run_dir) if not done(c)]


def command(evaluate: list[str], path: Path, run_dir: Path) -> list[str]:
    """The run's evaluation command (``train.evaluate``'s arguments) for one checkpoint, into its own folder."""
    args = list(evaluate)
    args[args.index("--out") + 1] = str(run_dir / FOLDER / path.name)
    return [*args, "--checkpoint", str(path)]


def commands(evaluate: list[str], paths: list[Path], run_dir: Path) -> list[list[str]]:
    """The evaluation commands for ``paths``: one for all of them (``train.evaluate --checkpoint A B ...``
    plays them in one batch, each into its own folder)."""
    if len(paths) < 2:
        return [command(evaluate, path, run_dir) for path in paths]
    args = list(evaluate)
    args[args.index("--out") + 1] = str(run_dir / FOLDER)
    return [[*args, "--checkpoint", *(str(p) for p in paths)]]


def write_clock(path: Path, run_dir: Path) -> None:
    """The checkpoint's env steps and training clock beside its evaluation."""
    meta = checkpoint.read_meta(path)
    clock = {"step": int(meta["step"]), "training_walltime_s": meta.get("training_walltime_s")}
    (run_dir / FOLDER / path.name / "clock.json").write_text(json.dumps(clock))


def as_final(run_dir: Path, final: Path) -> None:
    """The newest checkpoint's evaluation, once written, taken as the run's final one (``final``: the
    same arguments played on the same checkpoint) when that checkpoint is where the run ended: the run's
    checkpoints are played in one batch and the last is not played a second time."""
    found = checkpoint.list_checkpoints(run_dir)
    if not found or evaluated(run_dir / FOLDER / found[-1].name) is None:
        return
    ended = read_json(run_dir / "summary.json").get("env_steps")
    if ended is None or int(checkpoint.read_meta(found[-1])["step"]) != int(ended):
        return
    shutil.rmtree(final, ignore_errors=True)
    shutil.copytree(run_dir / FOLDER / found[-1].name, final, ignore=shutil.ignore_patterns("clock.json"))


def curve(run_dir: Path) -> list[dict[str, Any]]:
    """Every evaluated checkpoint of the run: env steps, training seconds, evaluated success; by step."""
    points = []
    for folder in sorted((run_dir / FOLDER).glob("step_*")):
        result, clock = evaluated(folder), read_json(folder / "clock.json")
        if result and clock:
            points.append({**clock, **result})
    return sorted(points, key=lambda p: p["step"])


def time_to_target(points: list[dict[str, Any]], target: float) -> dict[str, Any] | None:
    """The first evaluated checkpoint at or above ``target`` success: its training seconds and env steps."""
    for p in points:
        if p["success_rate"] >= target:
            return {"training_s": p["training_walltime_s"], "env_steps": p["step"], "success_rate": p["success_rate"]}
    return None


def markdown(report: dict[str, Any]) -> list[str]:
    """Each run's evaluated checkpoints: the time to the target and the success at each training clock."""
    runs = [r for r in report["runs"] if r.get("checkpoints")]
    if not runs:
        return []
    target = f"{report['target_success']:.0%}"
    header = f"| run | target ({target}) reached, evaluated | success at training seconds | first update from launch |"
    lines = ["", header]
    lines += ["|---|---|---|---|"]
    for r in runs:
        hit = r.get("evaluated_time_to_target")
        last = r["checkpoints"][-1]["training_walltime_s"] or 0.0
        reached = f"{hit['training_s']:.0f} s, {hit['env_steps']:,} env steps" if hit else f"not by {last:.0f} s"
        clock = [(p["success_rate"], p["training_walltime_s"] or 0.0) for p in r["checkpoints"]]
        points = ", ".join(f"{rate:.0%} at {seconds:.0f} s" for rate, seconds in clock)
        start = _startup(r.get("startup"), r.get("calls"))
        lines.append(f"| {r['arm']} seed {r['seed']} | {reached} | {points} | {start} |")
    if any((r.get("calls") or 1) > 1 for r in runs):
        lines += ["", RESUMED]
    return lines


def _startup(startup: dict[str, Any] | None, calls: int | None = None) -> str:
    """The run's (last call's) time from launch to its first update, whether its caches were cold, and the
    number of calls where it was resumed."""
    if not startup or startup.get("first_update_since_launch_s") is None:
        return "-"
    caches = "cold caches" if startup.get("cold_caches") else "warm caches"
    resumed = f", the last of {calls} calls" if calls and calls > 1 else ""
    return f"{startup['first_update_since_launch_s']:.0f} s, {caches}{resumed}"

"""The report of a sweep (``benchmarks.sweeps.run``): every run's evaluation and learning signs, each arm pooled
over its seeds with a 95 % interval, each arm against the first, a table and plots.

Per run: the evaluated success (goals reached with the mean action, on terrain the mean over its types at
the evaluated levels, each type's share beside it) with its Wilson interval, the first and the largest
logged value loss, the logged time to the target (``benchmarks.scaling.time_to_target``) and the run's wall-clock.
Per arm: the successes of all its seeds pooled (Wilson), each seed's figure, and the difference to the
first arm with Newcombe's interval. The pooled interval counts episodes, not seeds: the seeds' spread is
listed beside it, and a difference smaller than that spread is not read as a win.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from benchmarks.run_info import run_info
from benchmarks.scaling import time_to_target
from benchmarks.stats import difference_interval, wilson_interval
from benchmarks.sweeps import checkpoints
from benchmarks.sweeps import grid as sweep_grid
from benchmarks.sweeps.grid import read_json
from train.run.logger import read_jsonl

_JAX_KEYS = ("backend", "device", "device_count")  # this process keeps JAX on the CPU: its device says nothing
MODES = ("reached", "stuck", "lost", "slow", "terminated")  # train.evaluate's failure modes (docs/training.md)


def is_current(folder: Path, run_dir: Path) -> bool:
    """Whether ``folder`` holds an evaluation of the run's final checkpoint: its ``step`` is the run's env
    steps. A run trained further since (a sweep's ``env_steps`` raised) is evaluated again; an evaluation
    that names no step is taken as it is."""
    result = read_json(folder / "eval.json") or read_json(folder / "terrain_eval.json")
    steps = read_json(run_dir / "summary.json").get("env_steps")
    return bool(result) and (result.get("step") is None or steps is None or int(result["step"]) == int(steps))


def evaluation(run_dir: Path) -> dict[str, Any] | None:
    """A run's evaluation: successes, episodes, rate, interval (on terrain also each type's success and how
    the episodes ended, overall and per type); None before one (or when it evaluated an earlier checkpoint
    than the run's final one)."""
    if not is_current(run_dir / "sweep_eval", run_dir):
        return None
    flat, terrain = (
        read_json(run_dir / "sweep_eval" / "eval.json"),
        read_json(run_dir / "sweep_eval" / "terrain_eval.json"),
    )
    if terrain.get("rows"):
        rows = terrain["rows"]
        successes = int(sum(round(r["success_rate"] * r["episodes"]) for r in rows))
        episodes = int(sum(r["episodes"] for r in rows))
        per_type: dict[str, list[float]] = {}
        for r in rows:
            per_type.setdefault(r["type"], []).append(r["success_rate"])
        extra = {
            "per_type": {t: float(np.mean(v)) for t, v in per_type.items()},
            "modes": _modes(rows),
            "per_type_modes": {t: _modes([r for r in rows if r["type"] == t]) for t in per_type},
            "terrain_seed": terrain.get("terrain_seed"),
            "training_terrain_seed": terrain.get("training_terrain_seed"),
        }
    elif flat:
        episodes = int(flat["episodes"])
        successes, extra = int(round(flat["success_rate"] * episodes)), {"goal_range": flat.get("goal_range")}
    else:
        return None
    low, high = wilson_interval(successes, episodes)
    rate = successes / episodes
    return {"successes": successes, "episodes": episodes, "success_rate": rate, "ci95": [low, high], **extra}


def _modes(rows: list[dict]) -> dict[str, float] | None:
    """How a terrain evaluation's episodes ended (``train.evaluate``'s failure modes: reached, stuck, lost,
    slow, terminated), each a share of all its episodes; None for an evaluation without them."""
    if not all(r.get("modes") for r in rows):
        return None
    episodes = sum(r["episodes"] for r in rows)
    return {m: sum(r["modes"].get(m, 0.0) * r["episodes"] for r in rows) / episodes for m in MODES}


def _redraw_truncated_share(rows: list[dict]) -> float | None:
    """The share of a run's ended episodes that terrain re-draws cut short (None: the run logged no cut)."""
    cut = sum(r.get("terrain/redraw_truncations", 0.0) for r in rows)
    ended = sum(r.get("episodes", 0.0) for r in rows)
    return cut / (cut + ended) if cut > 0 else None


def learning(run_dir: Path, target_success: float) -> dict[str, Any] | None:
    """From a run's logs: the first and largest value loss, the time to the target, the wall-clock."""
    try:
        config, rows = time_to_target.read_run(run_dir)
    except (FileNotFoundError, ValueError):
        return None
    v_loss = [r["loss/v_loss"] for r in rows if isinstance(r.get("loss/v_loss"), (int, float))]
    return {
        "first_v_loss": v_loss[0] if v_loss else None,
        "max_v_loss": max(v_loss) if v_loss else None,
        "time_to_target": time_to_target.time_to_target(config, rows, target_success),
        "env_steps": int(rows[-1]["step"]),
        "redraw_truncated_share": _redraw_truncated_share(rows),
    }


def collect(sweep: Any, jobs: list) -> dict[str, Any]:
    """Every run's figures and every arm's pooled ones."""
    runs = []
    for job in jobs:
        summary = read_json(job.run_dir / "summary.json")
        curve = checkpoints.curve(job.run_dir)
        runs.append(
            {
                "arm": job.arm,
                "seed": job.seed,
                "run_dir": f"runs/{job.arm}/seed{job.seed}",
                "wall_s": summary.get("wall_s"),
                "physics_backend": summary.get("physics_backend"),
                "startup": summary.get("startup"),  # the last call's start-up parts (train/run/startup.py)
                "calls": summary.get("calls"),  # training calls: more than one when resumed from a checkpoint
                "learning": learning(job.run_dir, sweep.target_success),
                "evaluation": evaluation(job.run_dir),
                "checkpoints": curve,
                "evaluated_time_to_target": checkpoints.time_to_target(curve, sweep.target_success),
            }
        )
    arms = {arm: _pooled([r for r in runs if r["arm"] == arm]) for arm in sweep.arms}
    base = next(iter(sweep.arms))
    for arm, pooled in arms.items():
        if arm != base and pooled and arms[base]:
            d, low, high = difference_interval(
                (pooled["successes"], arms[base]["successes"]), (pooled["episodes"], arms[base]["episodes"])
            )
            spread = max(pooled["seed_spread"], arms[base]["seed_spread"])
            verdict = _verdict(d, low, high, spread)
            pooled["vs_first"] = {"arm": base, "difference": d, "ci95": [low, high], "verdict": verdict}
    return {"runs": runs, "arms": arms}


def _pooled(runs: list[dict]) -> dict[str, Any] | None:
    """One arm's evaluated runs pooled (None when none was evaluated)."""
    done = [r for r in runs if r["evaluation"]]
    if not done:
        return None
    successes = sum(r["evaluation"]["successes"] for r in done)
    episodes = sum(r["evaluation"]["episodes"] for r in done)
    seeds = {r["seed"]: r["evaluation"]["success_rate"] for r in done}
    pooled = {}  # on terrain: each type's success and the failure modes, weighted by the runs' episodes
    for key in ("per_type", "modes"):
        if all(r["evaluation"].get(key) for r in done):
            names = done[0]["evaluation"][key]
            pooled[key] = {
                k: sum(r["evaluation"][key][k] * r["evaluation"]["episodes"] for r in done) / episodes for k in names
            }
    return {
        "seeds_evaluated": len(done),
        "successes": successes,
        "episodes": episodes,
        "success_rate": successes / episodes,
        "ci95": list(wilson_interval(successes, episodes)),
        "per_seed": seeds,
        "seed_spread": max(seeds.values()) - min(seeds.values()),
        **pooled,
    }


def _verdict(difference: float, low: float, high: float, spread: float) -> str:
    """Better or worse only where the interval excludes 0 and the difference exceeds the seeds' spread."""
    if abs(difference) <= spread or low <= 0 <= high:
        return "not separated (within the interval or the seeds' spread)"
    return "better" if difference > 0 else "worse"


def markdown(report: dict[str, Any]) -> str:
    """The arms' table, then the runs' table."""
    lines = [f"# sweep {report['name']}", "", report.get("question", ""), ""]
    devices = report.get("devices") or []
    if len(set(devices)) < len(devices):  # a GPU named twice ran two runs at once
        lines += [
            f"{len(devices)} runs at once on {len(set(devices))} GPU(s) (`--devices {','.join(map(str, devices))}`): "
            "seconds are each run's clock as it ran beside the others, not one run's alone on a GPU.",
            "",
        ]
    lines += [
        "| arm | seeds | success (pooled) | 95 % interval | per seed | vs first arm (95 %) |",
        "|---|---|---|---|---|---|",
    ]
    for arm, a in report["arms"].items():
        if not a:
            lines.append(f"| {arm} | 0 | - | - | - | - |")
            continue
        vs = a.get("vs_first")
        versus = f"{vs['difference']:+.1%} ({vs['ci95'][0]:+.1%}, {vs['ci95'][1]:+.1%}): {vs['verdict']}" if vs else "-"
        seeds = ", ".join(f"{v:.0%}" for v in a["per_seed"].values())
        lines.append(
            f"| {arm} | {a['seeds_evaluated']} | {a['success_rate']:.1%} ({a['successes']}/{a['episodes']}) | "
            f"{a['ci95'][0]:.1%}-{a['ci95'][1]:.1%} | {seeds} | {versus} |"
        )
    lines += _pooled_tables(report["arms"])
    cuts = any((r["learning"] or {}).get("redraw_truncated_share") for r in report["runs"])  # re-draws cut episodes
    header = ["run", "success (95 %)", "first value loss", "largest value loss", "target reached at (s, env steps)"]
    header += ["episodes cut by re-draws"] if cuts else []
    lines += ["", "| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    for r in report["runs"]:
        ev, le = r["evaluation"], r["learning"] or {}
        hit = (le.get("time_to_target") or {}).get("reached")
        cut = le.get("redraw_truncated_share")
        lines.append(
            f"| {r['arm']} seed {r['seed']} | "
            + (f"{ev['success_rate']:.1%} ({ev['ci95'][0]:.0%}-{ev['ci95'][1]:.0%})" if ev else "not evaluated")
            + f" | {_g(le.get('first_v_loss'))} | {_g(le.get('max_v_loss'))} | "
            + (f"{hit['wall_s']} s, {hit['env_steps']:,}" if hit else "not reached")
            + (f" | {'none' if cut is None else f'{cut:.1%}'}" if cuts else "")
            + " |"
        )
    return "\n".join(lines) + "\n"


def _pooled_tables(arms: dict[str, Any]) -> list[str]:
    """On terrain: how each arm's episodes ended, and each type's success, pooled over its seeds."""
    done = {arm: a for arm, a in arms.items() if a}
    lines: list[str] = []
    if done and all(a.get("modes") for a in done.values()):
        lines += ["", "| arm | " + " | ".join(MODES) + " |", "|---" * (len(MODES) + 1) + "|"]
        lines += [f"| {arm} | " + " | ".join(f"{a['modes'][m]:.1%}" for m in MODES) + " |" for arm, a in done.items()]
    if done and all(a.get("per_type") for a in done.values()):
        lines += ["", "| type | " + " | ".join(done) + " |", "|---" * (len(done) + 1) + "|"]
        for t in next(iter(done.values()))["per_type"]:
            lines.append(
                f"| {t} | " + " | ".join(f"{a['per_type'].get(t, float('nan')):.1%}" for a in done.values()) + " |"
            )
    return lines


def _g(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


def plot_arm(arm: str, jobs: list, out: Path) -> Path:
    """One arm's seeds: logged success rate and value loss against env steps."""
    fig = Figure(figsize=(10, 3.6), layout="constrained")
    axes = fig.subplots(1, 2)
    for job in jobs:
        rows = read_jsonl(job.run_dir / "metrics.jsonl") if (job.run_dir / "metrics.jsonl").is_file() else []
        for ax, key in zip(axes, ("episode/success_rate", "loss/v_loss")):
            points = [(r["step"], r[key]) for r in rows if isinstance(r.get(key), (int, float))]
            if points:
                ax.plot(*zip(*points), label=f"seed {job.seed}")
    axes[0].set_title(f"{arm}: logged success rate")
    axes[1].set_title(f"{arm}: value loss (symlog)")
    axes[1].set_yscale("symlog")
    for ax in axes:
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
        if ax.get_lines():
            ax.legend(fontsize=8)
    path = out / f"arm_{arm}.png"
    fig.savefig(path, dpi=90)
    return path


def plot_arms(report: dict[str, Any], out: Path) -> Path:
    """Evaluated success per arm: each seed a dot, the pooled rate with its 95 % interval."""
    arms = [a for a in report["arms"] if report["arms"][a]]
    fig = Figure(figsize=(1.8 + 1.6 * max(1, len(arms)), 3.6), layout="constrained")
    ax = fig.subplots()
    for i, arm in enumerate(arms):
        a = report["arms"][arm]
        ax.errorbar(
            i,
            a["success_rate"],
            yerr=[[a["success_rate"] - a["ci95"][0]], [a["ci95"][1] - a["success_rate"]]],
            fmt="s",
            capsize=6,
            color="k",
        )
        ax.plot([i] * len(a["per_seed"]), list(a["per_seed"].values()), "o", alpha=0.6)
    ax.set_xticks(range(len(arms)), arms)
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("evaluated success (mean action)")
    ax.set_title(report["name"])
    ax.grid(alpha=0.3)
    path = out / "sweep.png"
    fig.savefig(path, dpi=90)
    return path


def write(
    sweep: Any,
    jobs: list,
    out: Path,
    gpus: list[str] | None = None,
    rewrite: bool = False,
    references: list | None = None,
    devices: list[str | None] | None = None,
) -> dict[str, Any]:
    """``sweep.json``, ``sweep.md``, ``sweep.png`` and one ``arm_<arm>.png`` per arm into ``out`` (``gpus``: the
    host's GPUs, recorded; ``devices``: the runs' devices, one entry a worker, so a GPU named k times ran k runs
    at once). ``rewrite``: a report written again from the runs keeps the host and date its
    runs were recorded with (the ``sweep.json`` already there), not this machine's. ``references``: the
    grid evaluation's reference policies (``benchmarks.sweeps.run.references``)."""
    out.mkdir(parents=True, exist_ok=True)
    before = read_json(out / "sweep.json") if rewrite else {}
    report = {
        "name": sweep.name,
        "question": sweep.question,
        "config": sweep.config,
        "arm_configs": sweep.arm_configs,
        "env_steps": sweep.env_steps,
        "budget_s": sweep.budget_s,
        "seeds": list(sweep.seeds),
        "common_overrides": list(sweep.common),
        "arms_overrides": {k: list(v) for k, v in sweep.arms.items()},
        "evaluate": sweep.evaluate,
        "target_success": sweep.target_success,
        **collect(sweep, jobs),
        "grid": sweep_grid.collect(list(sweep.arms), jobs, references or []),
        "gpus": before.get("gpus") or gpus or [],
        "devices": devices or before.get("devices") or [],
        "run_info": before.get("run_info") or {k: v for k, v in run_info().items() if k not in _JAX_KEYS},
    }
    (out / "sweep.json").write_text(json.dumps(report, indent=1))
    text = markdown(report)
    text += "\n".join(checkpoints.markdown(report)) + "\n" if checkpoints.markdown(report) else ""
    if report["grid"]:
        text += "\n".join(sweep_grid.markdown(report["grid"])) + "\n"
    (out / "sweep.md").write_text(text)
    for arm in sweep.arms:
        plot_arm(arm, [j for j in jobs if j.arm == arm], out)
    plot_arms(report, out)
    return report

"""Progress of track-task runs (corridor, spiral) whose episodes outlast a device call.

``python -m benchmarks.track_progress LABEL=RUN_DIR_OR_METRICS_JSONL ... --out FILE.png``

Corridor and spiral episodes run 4,000 and 8,000 steps; a 10-minute call gives each of thousands of
envs about half an episode, and a resumed call restarts every env, so finished-episode statistics
barely exist. What does show learning is the per-env-step batch mean the trainer logs
(``step/distance_to_goal``, ``step/reward``): within one call the whole batch walks from its start
distance towards its goals. This plots both against env steps for several runs and prints, per
call (a new call starts where the logged batch-mean distance jumps back up by more than 1 cm
while the batch-mean spiral checkpoint index does not rise: collected checkpoints also raise the
distance, to the next checkpoint; or where that index falls by more than 0.1: the envs restarted
from earlier checkpoints), the distance, checkpoint index and reward at its first and last log.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from train.logger import read_jsonl  # noqa: E402

RESTART_JUMP_M = 0.01  # a rise of the batch-mean distance this large between logs marks a restarted call
# a fall of the batch-mean checkpoint index this large, too: a few failed episodes restarting lower it
# by about index / num_envs (< 0.01 with thousands of envs); a restarted call by all collected so far
RESTART_INDEX_DROP = 0.1


def load(spec: str) -> tuple[str, list[dict]]:
    """``LABEL=PATH`` (a run dir or its metrics.jsonl) -> (label, records with per-step means)."""
    label, _, path = spec.partition("=")
    if not path:
        raise ValueError(f"expected LABEL=PATH, got {spec!r}")
    path = Path(path)
    path = path / "metrics.jsonl" if path.is_dir() else path
    if not path.is_file():
        raise FileNotFoundError(f"metrics file not found: {path}")
    records = [r for r in read_jsonl(path) if isinstance(r.get("step/distance_to_goal"), (int, float))]
    return label, records


def _checkpoint(record: dict) -> float:
    return float(record.get("step/checkpoint_index", 0.0))


def calls(records: list[dict]) -> list[list[dict]]:
    """Split a run's records into device calls (all envs restart: the distance jumps back up and the
    checkpoint index does not rise, or the checkpoint index falls)."""
    out: list[list[dict]] = []
    for record in records:
        prev = out[-1][-1] if out else None
        if prev is None or _restarted(prev, record):
            out.append([])
        out[-1].append(record)
    return out


def _restarted(prev: dict, record: dict) -> bool:
    """Whether the batch restarted between two consecutive logs."""
    jumped = record["step/distance_to_goal"] > prev["step/distance_to_goal"] + RESTART_JUMP_M
    return (jumped and _checkpoint(record) <= _checkpoint(prev)) or \
        _checkpoint(record) < _checkpoint(prev) - RESTART_INDEX_DROP


def table(runs: list[tuple[str, list[dict]]]) -> str:
    """Markdown: one row per call of each run."""
    lines = ["| run | call | env steps | distance to goal (batch mean, m) | checkpoint index (batch mean) "
             "| reward per step (batch mean) |", "|---|---|---|---|---|---|"]
    for label, records in runs:
        for i, call in enumerate(calls(records), 1):
            first, last = call[0], call[-1]
            lines.append(f"| {label} | {i} | {first['step']:,} -> {last['step']:,} | "
                         f"{first['step/distance_to_goal']:.3f} -> {last['step/distance_to_goal']:.3f} | "
                         f"{_checkpoint(first):.3f} -> {_checkpoint(last):.3f} | "
                         f"{first['step/reward']:+.3f} -> {last['step/reward']:+.3f} |")
    return "\n".join(lines)


def plot(runs: list[tuple[str, list[dict]]], out: Path) -> None:
    """Batch-mean distance to goal, spiral checkpoint index and reward per step against env steps."""
    fig, axes = plt.subplots(1, 3, figsize=(18, 4.5 + 0.25 * len(runs)), constrained_layout=True)
    for label, records in runs:
        for i, call in enumerate(calls(records)):
            steps = [r["step"] for r in call]
            color = f"C{runs.index((label, records))}"
            axes[0].plot(steps, [r["step/distance_to_goal"] for r in call], color=color, label=label if i == 0 else None)
            axes[1].plot(steps, [_checkpoint(r) for r in call], color=color)
            axes[2].plot(steps, [r["step/reward"] for r in call], color=color)
    for ax, title in zip(axes, ("distance to goal, batch mean (m); each call restarts the envs",
                                "spiral checkpoint index, batch mean", "reward per env step, batch mean")):
        ax.set_title(title)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    fig.legend(loc="outside lower center", ncols=1)
    fig.savefig(out, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    """Print the per-call table and write the plot."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.track_progress", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="LABEL=RUN_DIR or LABEL=metrics.jsonl")
    p.add_argument("--out", type=Path, required=True, help="PNG to write")
    args = p.parse_args(argv)
    runs = [load(spec) for spec in args.runs]
    print(table(runs))
    plot(runs, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

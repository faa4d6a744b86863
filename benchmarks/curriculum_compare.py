"""Compare the goal curriculum of several training runs: does it widen the same way on 1, 2 and 4 GPUs?

    python -m benchmarks.curriculum_compare LABEL=METRICS_JSONL [LABEL=METRICS_JSONL ...] --out FILE.png
        [--from-step N]

Plots ``curriculum/max_distance`` and the logged episode success rate against env steps and
against the curriculum's episode count (episodes it has seen, which is what its rule counts), one
line per run, and prints per run: the steps, episodes and training seconds at which each new maximum
was reached. Training seconds add up each log's env steps over its measured env-steps/s: the time
spent in epochs without the pauses between resumed calls (the first log after each start or
resume includes that call's compile).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence


def load(path: Path, from_step: int = 0) -> list[dict]:
    """The records of a ``metrics.jsonl`` at or after ``from_step`` (FileNotFoundError if missing)."""
    if not path.is_file():
        raise FileNotFoundError(f"metrics file not found: {path}")
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [r for r in records if r["step"] >= from_step]


def training_seconds(records: list[dict]) -> list[float]:
    """Cumulative time in training epochs at each record: env steps of each log over its env-steps/s."""
    total, out = 0.0, []
    for r in records:
        sps = r.get("training/env_steps_per_s") or 0.0
        total += r.get("env_steps", 0.0) / sps if sps > 0 else 0.0
        out.append(total)
    return out


def widenings(records: list[dict]) -> list[tuple[int, float, float, float]]:
    """(step, curriculum episode count, training s, new maximum) each time the range's maximum changed."""
    out, last = [], None
    for r, seconds in zip(records, training_seconds(records)):
        value = r.get("curriculum/max_distance")
        if value is not None and (last is None or abs(value - last) > 1e-6):
            out.append((r["step"], r.get("curriculum/episode_count", float("nan")), seconds, round(value, 3)))
            last = value
    return out


def plot(runs: dict[str, list[dict]], out: Path) -> None:
    """Four panels: max distance and success rate against env steps and against curriculum episodes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 2, figsize=(12, 8))
    for label, records in runs.items():
        steps = [r["step"] / 1e6 for r in records]
        episodes = [r.get("curriculum/episode_count", float("nan")) / 1e3 for r in records]
        dist = [r.get("curriculum/max_distance", float("nan")) for r in records]
        success = [r.get("episode/success_rate", float("nan")) for r in records]
        axes[0, 0].plot(steps, dist, label=label)
        axes[0, 1].plot(episodes, dist, label=label)
        axes[1, 0].plot(steps, success, ".", label=label)
        axes[1, 1].plot(episodes, success, ".", label=label)
    for ax, (y, x) in zip(axes.flat, [("curriculum max distance (m)", "env steps (M)"),
                                      ("curriculum max distance (m)", "curriculum episodes (k)"),
                                      ("episode success rate", "env steps (M)"),
                                      ("episode success rate", "curriculum episodes (k)")]):
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; 2 on bad arguments or missing files."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", metavar="LABEL=METRICS_JSONL")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--from-step", type=int, default=0, help="ignore records before this step (e.g. a resume)")
    args = p.parse_args(argv)
    try:
        pairs = [item.split("=", 1) for item in args.runs]
        bad = [item for item, pair in zip(args.runs, pairs) if len(pair) != 2]
        if bad:
            raise ValueError(f"expected LABEL=METRICS_JSONL, got {bad}")
        runs = {label: load(Path(path), args.from_step) for label, path in pairs}
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for label, records in runs.items():
        print(f"{label}: {len(records)} records; max distance reached "
              "(step, curriculum episodes, training s, metres):")
        for step, episodes, seconds, value in widenings(records):
            print(f"  {step:>12,}  {episodes:>10,.0f}  {seconds:>8,.0f}  {value}")
    plot(runs, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

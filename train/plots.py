"""Learning-curve plots from a run's ``metrics.jsonl`` (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from train.logger import read_jsonl  # noqa: E402

PANELS = (
    ("episode/return", "episode return"),
    ("episode/success_rate", "success rate"),
    ("curriculum/max_distance", "curriculum max goal distance (m)"),
    ("episode/final_distance", "final distance to goal (m)"),
    # per env step over the whole batch: progress on long (corridor, spiral) episodes before any ends
    ("step/reward", "reward per env step (batch mean)"),
    ("step/distance_to_goal", "distance to goal (batch mean, m)"),
    ("loss/total_loss", "PPO total loss (symlog)"),
    ("loss/policy_dist_mean_std", "policy std (mean)"),
    ("training/env_steps_per_s", "env-steps/s"),
)
LOG_SCALE = {"loss/total_loss"}


def learning_curves(metrics_path: str | Path, out_path: str | Path, title: str | None = None) -> Path | None:
    """Plot the headline metrics against env steps into ``out_path``; None if there is nothing to plot."""
    records = read_jsonl(metrics_path) if Path(metrics_path).is_file() else []
    if not records:
        return None
    steps = [r["step"] for r in records]
    fig, axes = plt.subplots(3, 3, figsize=(13, 10), constrained_layout=True)
    for ax, (key, label) in zip(axes.flat, PANELS):
        values = [r.get(key) for r in records]
        points = [(s, v) for s, v in zip(steps, values) if isinstance(v, (int, float))]
        if points:
            ax.plot(*zip(*points), marker="." if len(points) < 30 else None)
        if key in LOG_SCALE:
            ax.set_yscale("symlog")
        ax.set_title(label)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    fig.suptitle(title or str(Path(metrics_path).parent.name))
    out_path = Path(out_path)
    fig.savefig(out_path, dpi=100)
    plt.close(fig)
    return out_path

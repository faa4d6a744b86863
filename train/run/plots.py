"""Learning-curve plots from a run's ``metrics.jsonl`` (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from .logger import read_jsonl

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
    # the terrain curriculum (runs with it only)
    ("terrain/mean_level", "terrain level (mean over envs)"),
    ("terrain/top_share", "share of envs at the top terrain level"),
)
# what a PPO engineer reads first (train.learners.ppo.update), in a figure of their own
PPO_PANELS = (
    ("loss/v_loss", "value loss (symlog)"),
    ("loss/explained_variance", "explained variance of the returns"),
    ("loss/kl_mean", "KL from the collecting policy (symlog)"),
    ("loss/clip_fraction", "clip fraction"),
    ("loss/grad_norm", "gradient norm (before clipping)"),
    ("loss/learning_rate", "learning rate"),
    ("loss/policy_loss", "policy loss"),
    ("loss/entropy_loss", "entropy loss"),
    ("terrain/redraw_truncated_share", "share of episodes cut by terrain re-draws"),
)
# what an off-policy engineer reads first (train.learners.td3): the critics' values and their spread, the buffer
TD3_PANELS = (
    ("loss/critic_loss", "critic loss (cross-entropy)"),
    ("loss/actor_loss", "actor loss (minus the mean Q)"),
    ("loss/q_mean", "Q (mean over the batch)"),
    ("loss/q_std", "Q spread (std over the batch)"),
    ("loss/critic_grad_norm", "critic gradient norm"),
    ("loss/buffer_size", "transitions in the buffers"),
    ("loss/buffer_age", "age of sampled transitions (env steps)"),
    ("loss/noise_std_mean", "exploration noise (mean over envs)"),
    ("loss/skipped_updates", "skipped updates (non-finite)"),
)
DIAGNOSTICS = {"ppo": PPO_PANELS, "td3": TD3_PANELS}  # run.learner -> its panels
LOG_SCALE = {"loss/total_loss", "loss/v_loss", "loss/kl_mean", "loss/critic_loss"}


def learning_curves(metrics_path: str | Path, out_path: str | Path, title: str | None = None) -> Path | None:
    """Plot the headline metrics against env steps into ``out_path``; None if there is nothing to plot."""
    return _figure(metrics_path, out_path, PANELS, title)


def learner_diagnostics(metrics_path: str | Path, run_dir: str | Path, learner: str) -> Path | None:
    """The learner's diagnostics into ``run_dir / f"{learner}_diagnostics.png"``; None if nothing to plot."""
    return _figure(metrics_path, Path(run_dir) / f"{learner}_diagnostics.png", DIAGNOSTICS[learner], None)


def _figure(metrics_path: str | Path, out_path: str | Path, panels: tuple, title: str | None) -> Path | None:
    """One panel per (key, label) of ``panels`` that the records hold (terrain keys only when present)."""
    records = read_jsonl(metrics_path) if Path(metrics_path).is_file() else []
    if not records:
        return None
    steps = [r["step"] for r in records]
    panels = [p for p in panels if not p[0].startswith("terrain/") or any(p[0] in r for r in records)]
    columns = (len(panels) + 2) // 3
    width = 4.4 * columns
    fig = Figure(figsize=(width, 10))
    # fixed margins (inches) fit these short labels; constrained layout took 0.6 of the 1.3 s a figure drew
    fig.subplots_adjust(left=0.8 / width, right=1 - 0.35 / width, bottom=0.06, top=0.93, wspace=0.32, hspace=0.42)
    axes = fig.subplots(3, columns)
    for ax in axes.flat[len(panels) :]:
        ax.axis("off")
    for ax, (key, label) in zip(axes.flat, panels):
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
    return out_path


def terrain_grid(rows: list[dict], out_path: str | Path) -> Path:
    """Success rate and net progress per terrain type (rows) and difficulty (columns) as two heat maps."""
    types = list(dict.fromkeys(r["type"] for r in rows))
    levels = sorted({r["difficulty"] for r in rows})
    cell = {(r["type"], r["difficulty"]): r for r in rows}
    fig = Figure(figsize=(4 + 1.6 * len(levels), 1.5 + 0.45 * len(types)), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, (key, label, fmt) in zip(
        axes, (("success_rate", "success rate", "{:.0%}"), ("mean_progress_m", "net progress (m)", "{:.2f}"))
    ):
        grid = [[cell[(t, d)][key] for d in levels] for t in types]
        image = ax.imshow(
            grid,
            cmap="viridis",
            aspect="auto",
            vmin=0.0 if key == "success_rate" else None,
            vmax=1.0 if key == "success_rate" else None,
        )
        for i, line in enumerate(grid):
            for j, value in enumerate(line):
                ax.text(j, i, fmt.format(value), ha="center", va="center", color="w", fontsize=8)
        ax.set_xticks(range(len(levels)), [f"{d:g}" for d in levels])
        ax.set_yticks(range(len(types)), types)
        ax.set_xlabel("terrain difficulty")
        ax.set_title(label)
        fig.colorbar(image, ax=ax)
    out_path = Path(out_path)
    fig.savefig(out_path, dpi=100)
    return out_path

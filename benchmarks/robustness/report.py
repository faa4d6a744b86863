"""What ``benchmarks.robustness.score`` writes: the summary over cells, the markdown table, the heat map."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.stats import difference_interval
from hsa_mjx.deploy.perturbation import per_foot

TARGET = 0.9  # a cell "below 90 %" when its whole interval is
RESOLVING_EPISODES = 32  # a cell of 32 successes has its lower bound at 89 %: fewer cannot show 90 %


def summary(rows: list[dict], resolving_episodes: int) -> dict[str, Any]:
    """Lowest success and lowest lower bound (with their cells), the mean, the cells whose upper bound is
    below 90 %, and a note when too few episodes make the minimum mostly sampling noise."""
    worst = min(rows, key=lambda r: r["success_rate"])
    lowest = min(rows, key=lambda r: r["ci95"][0])
    episodes = min(r["episodes"] for r in rows)
    out = {
        "min_success_rate": worst["success_rate"],
        "min_success_cell": worst["label"],
        "lowest_lower_bound": lowest["ci95"][0],
        "lowest_lower_bound_cell": lowest["label"],
        "mean_success_rate": float(np.mean([r["success_rate"] for r in rows])),
        "cell_count": len(rows),
        "cells_upper_bound_below_90": sum(r["ci95"][1] < TARGET for r in rows),
    }
    if episodes < resolving_episodes:
        out["note"] = (
            f"{episodes} episodes a cell: the minimum over {len(rows)} cells is dominated by sampling noise "
            f"(one failure in {episodes} is {1 / episodes:.0%}); use {resolving_episodes} episodes on a GPU"
        )
    return out


def _feet(r: dict) -> str:
    """The feet's factors off 1 ("-" when none), each as its four values."""
    parts = [
        f"{name} x{per_foot(r[key])}"
        for key, name in (("foot_friction", "friction"), ("foot_anisotropy", "anisotropy"))
        if any(v != 1.0 for v in r.get(key, (1.0,)))
    ]
    return ", ".join(parts) or "-"


def _factors(r: dict) -> str:
    limit = "-" if r["servo_torque_limit"] is None else f"{r['servo_torque_limit']:g}"
    scales = " | ".join(f"x{r[k]:g}" for k in ("friction", "block_mass", "hsa_stiffness", "hsa_damping", "servo_gain"))
    flags = " | ".join("on" if r[k] else "off" for k in ("pushes", "noise"))
    return f"{scales} | {limit} | {_feet(r)} | {r.get('servo') or '-'} | {r['latency_ms']:g} | {flags}"


def rate(r: dict, episodes: bool = False) -> str:
    """A cell's success with its 95 % interval, e.g. "98% (95%-99%)" (and its episodes after the interval)."""
    low, high = r["ci95"]
    count = f", {r['episodes']}" if episodes else ""
    return f"{r['success_rate']:.0%} ({low:.0%}-{high:.0%}{count})"


def table(rows: list[dict]) -> str:
    """A markdown table: one row per cell, its success with the 95 % interval."""
    head = (
        "| friction | block mass | HSA stiffness | HSA damping | servo gain | torque limit (N m) | feet | servos "
        "| latency (ms) | pushes | noise | success (95 % CI) | progress (m) | failures ended by |"
    )
    lines = [head, "|" + "---|" * 14]
    for r in rows:
        ended = ", ".join(f"{k} {v:.0%}" for k, v in r["failures"].items()) or "-"
        lines.append(f"| {_factors(r)} | {rate(r)} | {r['mean_progress_m']:.2f} | {ended} |")
    return "\n".join(lines)


def sim_table(rows: list[dict]) -> str:
    """Sim-to-sim: each cell's MJX and C MuJoCo success and the gap (C minus MJX) with its paired interval."""
    lines = [
        "| cell | MJX (95 % CI) | C MuJoCo, deployment loop (95 % CI) | gap, points (95 % CI, paired) |",
        "|---|---|---|---|",
    ]
    for r in rows:
        mjx = {"success_rate": r["mjx_success_rate"], "ci95": r["mjx_ci95"]}
        low, high = r.get("gap_ci95", (r["gap"], r["gap"]))
        gap = f"{100 * r['gap']:+.0f} ({100 * low:+.0f} to {100 * high:+.0f})"
        lines.append(f"| {r['label']} | {rate(mjx)} | {rate(r)} | {gap} |")
    return "\n".join(lines)


def heat_map(rows: list[dict], path: Path, title: str) -> None:
    """Success rate as a heat map: the model down, sensing and disturbance (latency, pushes, noise) across."""
    from matplotlib.figure import Figure

    def model(r):
        scales = tuple(r[k] for k in ("friction", "block_mass", "hsa_stiffness", "hsa_damping", "servo_gain"))
        return (*scales, r["servo_torque_limit"], _feet(r), r.get("servo"))

    def sensing(r):
        return r["latency_ms"], r["pushes"], r["noise"]

    models, senses = list(dict.fromkeys(map(model, rows))), list(dict.fromkeys(map(sensing, rows)))
    grid = np.full((len(models), len(senses)), np.nan)
    for r in rows:
        grid[models.index(model(r)), senses.index(sensing(r))] = r["success_rate"]
    fig = Figure(figsize=(1.3 * len(senses) + 4, 0.45 * len(models) + 1.5))
    ax = fig.subplots()
    image = ax.imshow(grid, vmin=0, vmax=1, cmap="RdYlGn", aspect="auto")
    for (i, j), value in np.ndenumerate(grid):
        if np.isfinite(value):
            ax.text(j, i, f"{value:.0%}", ha="center", va="center", fontsize=8)
    ax.set_xticks(
        range(len(senses)),
        [f"{ms:g} ms" + (", pushes" if p else "") + (", noise" if n else "") for ms, p, n in senses],
        fontsize=8,
        rotation=30,
    )
    ax.set_yticks(range(len(models)), [_model_label(m) for m in models], fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.colorbar(image, ax=ax, label="success rate")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def _model_label(model: tuple) -> str:
    """A heat map row's name: the scales off 1 and the torque limit ("training model" when none)."""
    names = ("friction", "mass", "stiffness", "damping", "gain")
    parts = [f"{n} x{v:g}" for n, v in zip(names, model[:5]) if v != 1.0]
    parts += [f"torque <= {model[5]:g} N m"] if model[5] is not None else []
    parts += [f"feet: {model[6]}"] if model[6] != "-" else []
    parts += [f"servos: {model[7]}"] if model[7] else []
    return ", ".join(parts) or "training model"


def write(result: dict, out: Path, tag: str) -> list[str]:
    """Write ``robustness_<tag>.{json,md,png}`` under ``out``; the lines to print."""
    out.mkdir(parents=True, exist_ok=True)
    rows = result["cells"]
    for r in rows:
        r.pop("goals", None)
        r.pop("reached", None)
    (out / f"robustness_{tag}.json").write_text(json.dumps(result, indent=1))
    text = f"# {tag}: success per cell ({result['physics_backend']} physics)\n\n{table(rows)}\n"
    if result["sim_to_sim"]:
        text += f"\n## Sim-to-sim: the same cells on C MuJoCo's deployment loop\n\n{sim_table(result['sim_to_sim'])}\n"
    (out / f"robustness_{tag}.md").write_text(text)
    title = f"{tag}: success per cell ({result['episodes_per_cell']} episodes each, {result['physics_backend']})"
    heat_map(rows, out / f"robustness_{tag}.png", title)
    lines = [table(rows)]
    if result["sim_to_sim"]:
        lines.append(sim_table(result["sim_to_sim"]))
    lines.append(
        f"lowest success {result['min_success_rate']:.0%} ({result['min_success_cell']}); lowest lower bound "
        f"{result['lowest_lower_bound']:.0%} ({result['lowest_lower_bound_cell']}); mean "
        f"{result['mean_success_rate']:.0%}; {result['cells_upper_bound_below_90']} of {result['cell_count']} cells "
        f"below 90 % with 95 % confidence; wrote {out}/robustness_{tag}.{{json,md,png}}"
    )
    if "note" in result:
        lines.append(f"note: {result['note']}")
    return lines


def versus(arm: list[dict], reference: list[dict]) -> list[dict[str, Any]]:
    """Per cell, the arm minus the reference with its 95 % interval."""
    out = []
    for a, r in zip(arm, reference):
        d, low, high = difference_interval((a["successes"], r["successes"]), (a["episodes"], r["episodes"]))
        out.append({"label": a["label"], "difference": d, "ci95": [low, high]})
    return out

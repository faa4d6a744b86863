"""The grid part of a sweep's report (``evaluate.grid``): per cell of a ``benchmarks.robustness.score`` grid, each
arm's seeds pooled with a 95 % Wilson interval, each reference policy's figure, and each arm's difference
to each reference with Newcombe's interval.

Every run and reference plays the same episodes (the same seed: the same starts and goals in every
cell), but the report keeps only the counts, so the differences use the interval for independent
proportions, which is wider than a paired one would be.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.robustness.report import TARGET, rate, versus
from benchmarks.stats import wilson_interval

PLAYED = ("grid", "physics_backend", "episodes_per_cell", "seed", "where")


def read_json(path: Path) -> dict:
    """A JSON file's object, or {} where it is missing or unreadable (a run that did not get that far)."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def _cells(path: Path) -> list[dict] | None:
    """The cells of a finished grid evaluation (None before one, or where it is unreadable)."""
    return read_json(path).get("cells") or None


def _played(paths: list[Path]) -> list[dict[str, Any]]:
    """How the grid evaluations were played (grid, backend, episodes a cell, cells chosen), each setting once."""
    seen = []
    for path in paths:
        result = read_json(path)
        settings = {key: result.get(key) for key in PLAYED}
        if result.get("cells") and settings not in seen:
            seen.append(settings)
    return seen


def _pool(results: list[list[dict]]) -> list[dict[str, Any]]:
    """Cell by cell, the successes of several evaluations of the same grid added up."""
    pooled = []
    for rows in zip(*results):
        successes, episodes = sum(r["successes"] for r in rows), sum(r["episodes"] for r in rows)
        pooled.append(
            {
                "label": rows[0]["label"],
                "successes": successes,
                "episodes": episodes,
                "success_rate": successes / episodes,
                "ci95": list(wilson_interval(successes, episodes)),
                "per_seed": [r["success_rate"] for r in rows],
            }
        )
    return pooled


def _summary(cells: list[dict]) -> dict[str, Any]:
    worst = min(cells, key=lambda c: c["success_rate"])
    return {
        "mean_success_rate": float(np.mean([c["success_rate"] for c in cells])),
        "min_success_rate": worst["success_rate"],
        "min_success_cell": worst["label"],
        "cells_upper_bound_below_90": sum(c["ci95"][1] < TARGET for c in cells),
        "cell_count": len(cells),
    }


def collect(arms: list[str], jobs: list, references: list) -> dict[str, Any] | None:
    """The grid report: per arm (its evaluated seeds pooled) and per reference, with the differences."""
    refs = {job.run_dir.name: _cells(job.grid_result) for job in references}
    refs = {name: _pool([cells]) for name, cells in refs.items() if cells}
    out: dict[str, Any] = {"references": {}, "arms": {}}
    for name, cells in refs.items():
        out["references"][name] = {"cells": cells, **_summary(cells)}
    for arm in arms:
        seeds = [(job.seed, _cells(job.grid_result)) for job in jobs if job.arm == arm]
        done = [(seed, cells) for seed, cells in seeds if cells]
        if not done:
            continue
        cells = _pool([c for _, c in done])
        differences = {name: versus(cells, ref) for name, ref in refs.items()}
        out["arms"][arm] = {"seeds": [s for s, _ in done], "cells": cells, **_summary(cells), "versus": differences}
    out["played"] = _played([job.grid_result for job in [*references, *jobs]])
    return out if out["arms"] or out["references"] else None


def markdown(grid: dict[str, Any]) -> list[str]:
    """The grid section of ``sweep.md``: a row per cell, a column per reference and per arm (pooled)."""
    columns = [(f"`{n}`", r) for n, r in grid["references"].items()] + list(grid["arms"].items())
    refs = list(grid["references"])
    lines = ["", "## The grid, cell by cell (95 % intervals; arms pooled over their seeds)", ""]
    for p in grid.get("played", []):
        where = f", cells where {' and '.join(p['where'])}" if p.get("where") else ""
        episodes = p["episodes_per_cell"]
        seed = f", episode seed {p['seed']}" if p.get("seed") is not None else ""
        grid_name, backend = p["grid"], p["physics_backend"]
        lines.append(f"Played on {backend}: the {grid_name} grid, {episodes} episodes a cell{seed}{where}.")
    lines.append("")
    head = [name for name, _ in columns] + [f"{a} - `{r}`, points" for a in grid["arms"] for r in refs]
    lines += ["| cell | " + " | ".join(head) + " |", "|---|" + "---|" * len(head)]
    labels = [c["label"] for c in next(iter(columns))[1]["cells"]] if columns else []
    for i, label in enumerate(labels):
        row = [rate(col["cells"][i]) for _, col in columns]
        for arm in grid["arms"].values():
            for r in refs:
                v = arm["versus"][r][i]
                row.append(f"{100 * v['difference']:+.0f} ({100 * v['ci95'][0]:+.0f} to {100 * v['ci95'][1]:+.0f})")
        lines.append(f"| {label} | " + " | ".join(row) + " |")
    mean = [f"{col['mean_success_rate']:.1%}" for _, col in columns]
    low = [f"{col['min_success_rate']:.0%} ({col['min_success_cell']})" for _, col in columns]
    below = [f"{col['cells_upper_bound_below_90']} of {col['cell_count']}" for _, col in columns]
    pad = [""] * (len(head) - len(columns))
    for name, values in (("mean", mean), ("lowest cell", low), ("cells below 90 %", below)):
        lines.append(f"| **{name}** | " + " | ".join(values + pad) + " |")
    return lines

"""Writing throughput results: JSON rows, a markdown table and a log-log plot of steps/s vs batch."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

ROW_KEY = ("physics_backend", "terrain", "settings", "observation", "batch", "full_step", "regenerate_every")
# The project's speed targets (env-steps/s of the full step on one H200, Warp backend): heightfield at
# 16k+ envs, plane at 65k envs.
TARGETS = {"flat": 170_000, "heightfield": 120_000}


def slug(text: str) -> str:
    """File-name-safe lower-case form of a device name ("NVIDIA H200" -> "nvidia_h200")."""
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_") or "device"


def _observation(row: dict[str, Any]) -> str:
    """The row's observation (rows written before the column existed measured the original's)."""
    return row.get("observation", "original")


def _terrain(row: dict[str, Any]) -> str:
    """The row's terrain, with how often its random tiles were re-drawn when they were."""
    every = row.get("regenerate_every") or 0
    return f"{row['terrain']} (tiles re-drawn every {every} steps)" if every else row["terrain"]


def upsert(rows: list[dict[str, Any]], row: dict[str, Any]) -> list[dict[str, Any]]:
    """Rows with ``row`` added, replacing an earlier row of the same backend, terrain, settings, batch, kind."""
    key = tuple(row.get(k) for k in ROW_KEY)
    return [r for r in rows if tuple(r.get(k) for k in ROW_KEY) != key] + [row]


def load_rows(path: Path) -> list[dict[str, Any]]:
    """Rows of an earlier results file (empty when there is none)."""
    if not path.is_file():
        return []
    return list(json.loads(path.read_text()).get("rows", []))


def fmt(value: Any, digits: int = 0) -> str:
    """A table cell: thousands separators, ``digits`` decimals for floats, - for None."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:,.{digits}f}"
    return f"{value:,}" if isinstance(value, int) else str(value)


def _reasons(rates: dict[str, float] | None) -> str:
    """Termination reasons by rate, e.g. "qacc_limit 1,200; non_finite 3" (- when none)."""
    if not rates:
        return "-"
    return "; ".join(f"{k} {v:,.0f}" for k, v in sorted(rates.items(), key=lambda kv: -kv[1]))


def markdown(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The results as a markdown table with the provenance above it."""
    head = [
        f"Throughput on {meta.get('device')} ({meta.get('backend')}), {meta.get('date')}; "
        f"versions {meta.get('versions')}; command `{meta.get('command')}`.",
        "",
        "| backend | terrain | settings | observation | batch | env-steps/s | ceiling env-steps/s | env / ceiling | "
        "compile env s | compile ceiling s | MiB/env (XLA) | NaN per M steps | ceiling NaN per M | "
        "non-finite obs | full step | C MuJoCo env-steps/s | terminations per M steps |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (_backend(r), _terrain(r), r["settings"], _observation(r), r["batch"])):
        mib = r.get("env_compiled_bytes_per_env")
        mib = None if mib is None else mib / 2**20
        head.append(
            f"| {_backend(r)} | {_terrain(r)} | {r['settings']} | {_observation(r)} | {r['batch']:,} | "
            f"{fmt(r['env_steps_per_s'])} | "
            f"{fmt(r['physics_ceiling_env_steps_per_s'])} | {fmt(r['env_over_ceiling'], 2)} | "
            f"{fmt(r['compile_s_env'], 1)} | {fmt(r['compile_s_ceiling'], 1)} | "
            f"{fmt(mib, 3)} | {fmt(r['nan_terminations_per_million_env_steps'], 1)} | "
            f"{fmt(r.get('ceiling_non_finite_per_million_env_steps'), 1)} | "
            f"{'yes' if r['obs_non_finite_seen'] else 'no'} | {'yes' if r['full_step'] else 'no'} | "
            f"{fmt(r.get('cpu_mujoco_env_steps_per_s'))} | {_reasons(r.get('terminations_per_million_env_steps'))} |"
        )
    return "\n".join(head) + "\n"


def plot(rows: list[dict[str, Any]], meta: dict[str, Any], path: Path) -> None:
    """Log-log env-steps/s against batch: env (solid) and physics ceiling (dashed) per terrain/setting."""
    import matplotlib.ticker
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 5))
    ax = fig.subplots()
    groups = sorted({(_backend(r), _terrain(r), r["settings"], _observation(r)) for r in rows})
    for i, group in enumerate(groups):
        pts = sorted(
            (r["batch"], r["env_steps_per_s"], r["physics_ceiling_env_steps_per_s"])
            for r in rows
            if (_backend(r), _terrain(r), r["settings"], _observation(r)) == group
        )
        batch, env, ceiling = zip(*pts)
        color, name = f"C{i}", ", ".join(group)
        ax.plot(batch, env, "o-", color=color, label=f"{name}: env step")
        if None not in ceiling:  # rows measured with --no-ceiling have none
            ax.plot(batch, ceiling, "s--", color=color, alpha=0.7, label=f"{name}: bare mjx.step")
    for terrain, target in sorted(TARGETS.items()):
        if any(r["terrain"] == terrain for r in rows):
            ax.axhline(target, color="grey", ls=":", lw=1)
            ax.annotate(
                f"target {terrain} {target:,}",
                (0.01, target),
                xycoords=("axes fraction", "data"),
                fontsize=7,
                color="grey",
                va="bottom",
            )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    batches = sorted({r["batch"] for r in rows})
    ax.set_xticks(batches, [f"{b // 1024}k" if b >= 1024 and b % 1024 == 0 else str(b) for b in batches])
    ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
    ax.set_xlabel("envs (batch)")
    ax.set_ylabel("env steps / s (0.02 s control steps)")
    ax.set_title(f"{meta.get('device')} - {meta.get('date', '')[:10]}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def _backend(row: dict[str, Any]) -> str:
    """The row's physics backend (rows measured before the choice existed ran on JAX)."""
    return row.get("physics_backend") or "jax"


def write_all(out_dir: Path, stem: str, rows: list[dict[str, Any]], meta: dict[str, Any]) -> list[Path]:
    """Write ``stem``.json, .md and .png into ``out_dir``; return the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"{stem}.{ext}" for ext in ("json", "md", "png")]
    paths[0].write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    paths[1].write_text(markdown(rows, meta))
    if rows:
        plot(rows, meta, paths[2])
    return paths

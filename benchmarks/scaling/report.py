"""Writing scaling results: speed-ups, JSON rows, a markdown table and a plot of env-steps/s against devices."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

# (row key of the rate, name in the table and the plot)
RATES = (
    ("env_steps_per_s", "env step"),
    ("ppo_env_steps_per_s", "PPO with updates"),
    ("collect_env_steps_per_s", "PPO collection only"),
)
SPEEDUP_RATES = RATES[:2]


def with_speedups(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows with ``speedup_<rate>`` and ``efficiency_<rate>`` relative to the fewest devices measuring it."""
    out = [dict(r) for r in rows]
    for key, _ in SPEEDUP_RATES:
        measured = [r for r in out if r.get(key)]
        if not measured:
            continue
        base = min(measured, key=lambda r: r["devices"])
        for r in measured:
            speedup = r[key] / base[key]
            r[f"speedup_{key}"] = round(speedup, 3)
            r[f"efficiency_{key}"] = round(speedup * base["devices"] / r["devices"], 3)
            r[f"speedup_base_devices_{key}"] = base["devices"]
    return out


def _fmt(value: Any, digits: int = 0, scale: float = 1.0) -> str:
    """A table cell: thousands separators, ``digits`` decimals, times ``scale``; "-" when missing."""
    if value is None:
        return "-"
    return f"{value * scale:,.{digits}f}"


# (header, row key, digits, scale) of the table's columns
COLUMNS = (
    ("devices", "devices", 0, 1),
    ("envs", "num_envs", 0, 1),
    ("env step env-steps/s", "env_steps_per_s", 0, 1),
    ("speed-up", "speedup_env_steps_per_s", 2, 1),
    ("efficiency %", "efficiency_env_steps_per_s", 0, 100),
    ("PPO env-steps/s", "ppo_env_steps_per_s", 0, 1),
    ("speed-up", "speedup_ppo_env_steps_per_s", 2, 1),
    ("efficiency %", "efficiency_ppo_env_steps_per_s", 0, 100),
    ("collection env-steps/s", "collect_env_steps_per_s", 0, 1),
    ("update %", "update_fraction", 0, 100),
    ("compile s env", "env_compile_s", 1, 1),
    ("compile s PPO", "ppo_compile_s", 1, 1),
)


def markdown(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The results as a markdown table with the provenance above it."""
    lines = [
        f"Scaling on {meta.get('device')} x {meta.get('device_count')} ({meta.get('backend')}), "
        f"{meta.get('date')}; {meta.get('envs_per_device'):,} envs per device, config `{meta.get('config')}`; "
        f"versions {meta.get('versions')}; command `{meta.get('command')}`.",
        "",
        "Speed-up and efficiency (speed-up / device ratio) are relative to the fewest devices measured; "
        "`update %` is the share of a PPO epoch not spent collecting (epoch minus collection alone).",
        "",
        "| " + " | ".join(c[0] for c in COLUMNS) + " |",
        "|" + "---|" * len(COLUMNS),
    ]
    for r in sorted(rows, key=lambda r: r["devices"]):
        lines.append("| " + " | ".join(_fmt(r.get(key), digits, scale) for _, key, digits, scale in COLUMNS) + " |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict[str, Any]], meta: dict[str, Any], path: Path) -> None:
    """Env-steps/s against devices (log-log) with the ideal linear line from the fewest devices; efficiency."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.5))
    speed, eff = fig.subplots(1, 2)
    counts = sorted({r["devices"] for r in rows})
    for i, (key, label) in enumerate(RATES):
        pts = sorted((r["devices"], r[key]) for r in rows if r.get(key))
        if not pts:
            continue
        devices, rates = zip(*pts)
        speed.plot(devices, rates, "o-", color=f"C{i}", label=label)
        speed.plot(
            counts,
            [rates[0] * k / devices[0] for k in counts],
            ":",
            color=f"C{i}",
            alpha=0.7,
            label=f"{label}: ideal linear",
        )
        effs = [(r["devices"], 100 * r[f"efficiency_{key}"]) for r in rows if r.get(f"efficiency_{key}")]
        if effs:
            eff.plot(*zip(*sorted(effs)), "o-", color=f"C{i}", label=label)
    speed.set_xscale("log", base=2)
    speed.set_yscale("log")
    speed.set_ylabel("env steps / s")
    eff.axhline(100, color="grey", ls=":", lw=1)
    eff.set_ylabel("efficiency % (speed-up / devices)")
    eff.set_ylim(bottom=0)
    for ax in (speed, eff):
        ax.set_xticks(counts, [str(c) for c in counts])
        ax.set_xlabel("devices")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(
        f"{meta.get('device')}: {meta.get('envs_per_device'):,} envs per device - {str(meta.get('date', ''))[:10]}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def write_all(out_dir: Path, stem: str, rows: list[dict[str, Any]], meta: dict[str, Any]) -> list[Path]:
    """Write ``stem``.json, .md and .png (the plot once a row has a rate) into ``out_dir``; return the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, md_path, png_path = (out_dir / f"{stem}.{ext}" for ext in ("json", "md", "png"))
    json_path.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    md_path.write_text(markdown(rows, meta))
    if any(r.get(key) for r in rows for key, _ in RATES):
        plot(rows, meta, png_path)
        return [json_path, md_path, png_path]
    return [json_path, md_path]

"""Are two training runs the same run? Their logged metrics side by side, step by step, and their speed.

    python -m benchmarks.scaling.same_run RUN_A RUN_B [--names A B] [--note TEXT] [--out FILE.json [--append]]

Reads each run dir's ``metrics.jsonl`` (or the files given) and, for every step both logged,
counts the metrics that are equal and names the largest difference; the clock's records (wall
time, speed, time since launch) are not compared but reported: each run's env steps per second.
The JSON holds every compared metric's two values per step. Exit status 0 when every compared
metric is within ``--tolerance`` (relative, default 0: equal), 1 otherwise. Written as JSON and
Markdown beside ``--out``. Used to check that several processes train exactly as one process over
the same devices (docs/scaling.md).
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.run_info import report

CLOCK = ("time", "training/walltime", "training/env_steps_per_s", "training/since_launch")
SPEED = "training/env_steps_per_s"


def read_records(path: str | Path) -> list[dict]:
    """A run's log records (``path``: the run dir or its ``metrics.jsonl``); FileNotFoundError if absent."""
    path = Path(path)
    file = path / "metrics.jsonl" if path.is_dir() else path
    if not file.is_file():
        raise FileNotFoundError(f"no metrics log at {file} (give a run dir or its metrics.jsonl)")
    return [json.loads(line) for line in file.read_text().splitlines() if line.strip()]


def _gap(a: Any, b: Any) -> float:
    """Relative difference |a - b| / max(1, |a|, |b|); 0 for equal values (NaN equal to NaN)."""
    if a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)):
        return 0.0
    return abs(a - b) / max(1.0, abs(a), abs(b))


def compare_step(a: dict, b: dict) -> dict:
    """One step's comparison: metrics compared and equal, the largest gap and its metric, both speeds,
    and every compared metric's two values side by side."""
    keys = sorted(k for k in a.keys() & b.keys() if k not in CLOCK and isinstance(a[k], (int, float)))
    gaps = {k: _gap(a[k], b[k]) for k in keys}
    worst = max(gaps, key=gaps.get) if gaps else None
    return {
        "step": a["step"],
        "compared": len(keys),
        "equal": sum(g == 0.0 for g in gaps.values()),
        "largest_gap": gaps[worst] if worst else 0.0,
        "largest_gap_metric": worst if worst and gaps[worst] > 0 else None,
        "speeds": [a.get(SPEED), b.get(SPEED)],
        "metrics": {k: [a[k], b[k]] for k in keys},
    }


def compare(runs: Sequence[list[dict]]) -> list[dict]:
    """Every step both runs logged, compared (in step order)."""
    by_step = [{r["step"]: r for r in records} for records in runs]
    return [compare_step(by_step[0][s], by_step[1][s]) for s in sorted(by_step[0].keys() & by_step[1].keys())]


def to_markdown(result: dict) -> str:
    """The comparison as a Markdown table."""
    a, b = result["names"]
    lines = [
        f"# Same run? `{a}` against `{b}`",
        "",
        f"Tolerance {result['tolerance']} (relative); same: **{result['same']}**.",
        "",
        *([result["note"], ""] if result.get("note") else []),
        f"| step | metrics compared | equal | largest gap (metric) | {a} env steps/s | {b} env steps/s |",
        "|---|---|---|---|---|---|",
    ]
    for row in result["steps"]:
        gap = f"{row['largest_gap']:.2g} ({row['largest_gap_metric']})" if row["largest_gap_metric"] else "0"
        speeds = [f"{s:,.0f}" if s is not None else "-" for s in row["speeds"]]
        lines.append(f"| {row['step']:,} | {row['compared']} | {row['equal']} | {gap} | {speeds[0]} | {speeds[1]} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs=2, help="two run dirs (or metrics.jsonl files)")
    p.add_argument("--names", nargs=2, default=None, help="what to call the two runs (default: their paths)")
    p.add_argument("--tolerance", type=float, default=0.0, help="largest relative gap counted as the same")
    p.add_argument("--note", default="", help="where and how the runs were made (kept in the files)")
    p.add_argument("--out", type=Path, default=None, help="write FILE.json and FILE.md")
    p.add_argument("--append", action="store_true", help="add this comparison to what --out's files hold")
    args = p.parse_args(argv)
    if args.tolerance < 0:
        raise ValueError(f"--tolerance must be >= 0, got {args.tolerance}")
    steps = compare([read_records(r) for r in args.runs])
    if not steps:
        raise ValueError(f"{args.runs[0]} and {args.runs[1]} logged no step in common")
    same = all(row["largest_gap"] <= args.tolerance for row in steps)
    result = {
        "names": args.names or list(args.runs),
        "tolerance": args.tolerance,
        "same": same,
        "note": args.note,
        "steps": steps,
    }
    report(args.out, result, to_markdown(result), append=args.append)
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())

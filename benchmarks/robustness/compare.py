"""Two policies' robustness results, cell by cell: ``python -m benchmarks.robustness.compare A.json B.json``.

For every cell both results played (matched by the cell's label), each policy's success with its
95 % Wilson interval and A minus B with Newcombe's interval (the two results' episodes are
independent draws: different policies, and possibly other seeds or episode counts). A difference is
called only where its interval excludes zero. Prints a markdown table, with ``--out FILE`` also
writes it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from benchmarks.robustness.merge import read_part
from benchmarks.robustness.report import rate, versus

NEEDED = ("policy", "physics_backend", "episodes_per_cell")  # what the table's heading names


def compare(a: dict[str, Any], b: dict[str, Any]) -> list[dict[str, Any]]:
    """A row per cell of ``a`` that ``b`` also played: both scores and A - B with its 95 % interval."""
    theirs = {c["label"]: c for c in b["cells"]}
    pairs = [(mine, theirs[mine["label"]]) for mine in a["cells"] if mine["label"] in theirs]
    if not pairs:
        raise ValueError("the two results share no cell: nothing to compare")
    rows = []
    for (mine, other), d in zip(pairs, versus([m for m, _ in pairs], [o for _, o in pairs])):
        low, high = d["ci95"]
        verdict = "A better" if low > 0 else "B better" if high < 0 else "not separated"
        rows.append({**d, "a": mine, "b": other, "verdict": verdict})
    return rows


def markdown(rows: list[dict[str, Any]], a: dict[str, Any], b: dict[str, Any]) -> str:
    """The comparison as a markdown table, headed by what each side played."""

    def played(r: dict) -> str:
        return f"`{Path(r['policy']).name}` ({r['physics_backend']}, {r['episodes_per_cell']} episodes a cell)"

    lines = [
        f"A: {played(a)}; B: {played(b)}; {len(rows)} shared cells.",
        "",
        "| cell | A (95 %, episodes) | B (95 %, episodes) | A - B, points (95 %) | |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        low, high = (100 * v for v in r["ci95"])
        diff = f"{100 * r['difference']:+.0f} ({low:+.0f} to {high:+.0f})"
        scores = " | ".join(rate(r[side], episodes=True) for side in ("a", "b"))
        lines.append(f"| {r['label']} | {scores} | {diff} | {r['verdict']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.robustness.compare``."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.robustness.compare",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("a", metavar="A.json", help="a benchmarks.robustness.score result")
    parser.add_argument("b", metavar="B.json", help="another, compared against")
    parser.add_argument("--out", default=None, help="also write the table to this markdown file")
    args = parser.parse_args(argv)
    try:
        a, b = (read_part(Path(p), NEEDED) for p in (args.a, args.b))
        text = markdown(compare(a, b), a, b)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(text, end="")
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

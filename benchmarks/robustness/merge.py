"""Join the parts of one robustness grid: ``python -m benchmarks.robustness.merge PART.json ... --tag TAG``.

A long grid (many episodes a cell, ``--sim-to-sim``) can be played in parts, one call or machine
each: ``python -m benchmarks.robustness.score POLICY ... --part 1/2``, then ``--part 2/2`` (or disjoint
``--where`` selections). The parts must agree on everything but their cells (policy, grid, episodes,
seed, steps, backend, rules, noise and pushes); their cells are joined in the grid's order and the
summary is computed over all of them. The joined result keeps the first part's provenance and each
part's command, date, device and commit under ``parts``; it is written as ``benchmarks.robustness.score``
writes one (``robustness_<tag>.{json,md,png}``).

A joined result can be a part again: it is split back into its parts (each part's cells are the ones
its ``--where`` and ``--part`` choose). With ``--replace`` a later part's cells replace the same cells
of earlier parts (a part played again, e.g. with ``--sim-to-sim``); an earlier part left without a
cell drops out, its provenance with it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from benchmarks.robustness import grids, report

# what every part of one grid shares
SAME = (
    "policy",
    "grid",
    "episodes_per_cell",
    "seed",
    "max_steps",
    "physics_backend",
    "qacc_rule",
    "noise_on",
    "pushes_on",
)
PROVENANCE = ("command", "date", "host", "device", "git_commit", "git_dirty", "where", "part")


def read_part(path: Path, keys: tuple[str, ...] = SAME) -> dict[str, Any]:
    """One result with ``keys``, its cells and sim-to-sim rows (FileNotFoundError or ValueError naming
    the file and what is missing)."""
    if not path.is_file():
        raise FileNotFoundError(f"no robustness result at {path}")
    try:
        result = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not JSON: {err}") from err
    missing = [k for k in (*keys, "cells", "sim_to_sim") if k not in result]
    if missing:
        raise ValueError(f"{path} is not a benchmarks.robustness.score result: no {', '.join(missing)}")
    return result


def split(result: dict[str, Any]) -> list[dict[str, Any]]:
    """A joined result as its parts (each with its provenance and the cells its selection chose); a
    result that was not joined, as itself."""
    if not result.get("parts"):
        return [result]
    shared = {k: v for k, v in result.items() if k not in ("parts", "cells", "sim_to_sim")}
    cells = grids.grid(result["grid"])
    out = []
    for provenance in result["parts"]:
        chosen = {grids.label(c) for c in grids.part(grids.select(cells, provenance["where"]), provenance["part"])}
        out.append(
            {
                **shared,
                **provenance,
                "cells": [r for r in result["cells"] if r["label"] in chosen],
                "sim_to_sim": [r for r in result["sim_to_sim"] if r["label"] in chosen],
            }
        )
    return out


def replaced(parts: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The parts with each cell kept from the last part that played it; parts left without a cell dropped."""
    later: set[str] = set()
    kept = []
    for result in reversed(parts):
        mine = {r["label"] for r in result["cells"]}
        cells = [r for r in result["cells"] if r["label"] not in later]
        sims = [r for r in result["sim_to_sim"] if r["label"] not in later]
        later |= mine
        if cells:
            kept.append({**result, "cells": cells, "sim_to_sim": sims})
    return kept[::-1]


def merge(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """The parts joined into one result (ValueError where they differ or share a cell)."""
    if not parts:
        raise ValueError("no parts to join")
    first = parts[0]
    for i, result in enumerate(parts[1:], 2):
        differ = [k for k in SAME if result[k] != first[k]]
        if differ:
            raise ValueError(f"part {i} differs from part 1 in {', '.join(differ)}: not parts of one grid")
    order = [grids.label(c) for c in grids.grid(first["grid"])]
    cells = [r for result in parts for r in result["cells"]]
    labels = [r["label"] for r in cells]
    repeated = sorted({name for name in labels if labels.count(name) > 1})
    if repeated:
        raise ValueError(f"cells played in more than one part: {', '.join(repeated)}")
    rank = {name: i for i, name in enumerate(order)}
    unknown = [name for name in labels if name not in rank]
    if unknown:
        raise ValueError(f"cells not in the {first['grid']} grid: {', '.join(unknown)}")
    cells.sort(key=lambda r: rank[r["label"]])
    sims = sorted((r for result in parts for r in result["sim_to_sim"]), key=lambda r: rank[r["label"]])
    summary = report.summary(cells, report.RESOLVING_EPISODES)
    kept = {k: v for k, v in first.items() if k not in (*summary, "note", "cells", "sim_to_sim", "parts")}
    return {
        **kept,
        "where": [],
        "part": None,
        "parts": [{k: result.get(k) for k in PROVENANCE} for result in parts],
        **summary,
        "cells": cells,
        "sim_to_sim": sims,
    }


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.robustness.merge``."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.robustness.merge",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("parts", nargs="+", metavar="PART.json", help="the parts' robustness_<tag>.json files")
    parser.add_argument("--tag", required=True, help="the joined files' tag: robustness_<tag>.{json,md,png}")
    parser.add_argument("--out-dir", default=None, help="where to write (default: the first part's folder)")
    parser.add_argument(
        "--replace", action="store_true", help="a later part's cells replace the same cells of earlier parts"
    )
    args = parser.parse_args(argv)
    try:
        parts = [split_part for p in args.parts for split_part in split(read_part(Path(p)))]
        joined = merge(replaced(parts) if args.replace else parts)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    out = Path(args.out_dir) if args.out_dir else Path(args.parts[0]).parent
    for line in report.write(joined, out, args.tag):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())

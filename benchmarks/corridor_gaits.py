"""Can the robot move in the corridor? Open-loop gaits for 20 s in corridor layouts and on the plane.

``python -m benchmarks.corridor_gaits [--seconds 20] [--out benchmarks/results/corridor_gaits_cpu]``
plays the fidelity guard's gaits (benchmarks/gaits.py) through the env at the track tasks' servo
range (6.28 rad) and the shipped heightfield physics, and writes the robot's displacement per gait
and layout as JSON and a markdown table. The layouts: the corridor preset (the original's floor of
three vertex rows, offset +0.102 m), the same corridor centred on the robot (width 0.6: only two
vertex rows of floor), and the plane.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import hsa_mjx
from benchmarks import fidelity
from benchmarks.run_info import write_table_result
from hsa_mjx import config as ec

GAITS = ("extend_contract", "crawl", "sine", "wave")
PHYSICS = {"integrator": "implicitfast", "iterations": 8, "ls_iterations": 8}
LAYOUTS = {
    "corridor_preset": ("corridor", {}),
    "corridor_centred_0.6": ("corridor", {"terrain": {"corridor": {"corridor_width": 0.6, "center": 0.5}}}),
    "plane": ("flat", {"control": {"servo_target_limit": 6.28}}),
}


def displacements(layout: str, seconds: float) -> list[dict]:
    """Robot (x, y) displacement after ``seconds`` of each gait in one layout."""
    preset, extra = LAYOUTS[layout]
    env = hsa_mjx.make_env(ec.from_dict({"physics": PHYSICS, **extra}, base=ec.get_preset(preset)))
    actions = jnp.asarray(fidelity.gait_matrix(GAITS, seconds))
    start, xy, fails = jax.device_get(fidelity.mjx_rollout_fn(env)(actions))
    rows = []
    for g, gait in enumerate(GAITS):
        dx, dy = (np.asarray(xy[g, -1]).mean(0) - np.asarray(start[g]).mean(0)).tolist()
        rows.append({"layout": layout, "gait": gait, "seconds": seconds, "dx_m": round(dx, 3), "dy_m": round(dy, 3),
                     "failures": {k: int(v[g]) for k, v in fails.items() if int(v[g])}})
    return rows


def markdown(rows: list[dict]) -> str:
    """One row per layout, one column per gait: displacement along the corridor (x) and across (y)."""
    lines = ["| layout | " + " | ".join(GAITS) + " |", "|---|" + "---|" * len(GAITS)]
    for layout in dict.fromkeys(r["layout"] for r in rows):
        cells = [f"{r['dx_m']:+.3f}, {r['dy_m']:+.3f}" for r in rows if r["layout"] == layout]
        lines.append(f"| {layout} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Run every layout, print and write the table."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.corridor_gaits", description=__doc__)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--layouts", nargs="+", default=list(LAYOUTS), choices=list(LAYOUTS))
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/corridor_gaits_cpu"))
    args = p.parse_args(argv)
    tic, rows = time.perf_counter(), []
    for layout in args.layouts:
        rows += displacements(layout, args.seconds)
    table = f"Robot displacement (dx, dy) in m after {args.seconds:g} s of each open-loop gait\n\n" + markdown(rows)
    write_table_result(args.out, table, rows, tic)


if __name__ == "__main__":
    main()

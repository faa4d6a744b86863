"""What the robot can pass: the highest step, the steepest slope and the narrowest gap, measured.

    python -m benchmarks.terrain.capability [--policy rough] [--episodes 4] [--backend c]
        [--out benchmarks/results/capability]

**Geometry.** From the model at its spawn pose: the robot's length, the width of its blocks (the parts
that touch the ground) and its full width with the HSA units, and how high above the ground the units'
underside sits (a wall lower than that meets only the blocks).

**Simulation.** One feature on the terrain heightfield straight ahead of the spawn, the goal straight
beyond it, a trained policy (its mean action) for ``--episodes`` episodes per value, each through
``train.episodes.play.evaluate``'s per-terrain evaluation (what ``python -m train.evaluate --terrain-types`` runs):

- **step**: ``flat_with_ramp`` across the whole field, turned to face the robot with its high edge: a
  rise of h over one heightfield cell (0.2 m) at 1.2 m from the spawn, then a gentle slope down; goal
  at 2.0 m;
- **slope**: ``flat_with_incline`` across the whole field, 1.2 m long from 1.1 m (flat on top where it
  would pass the heightfield's 0.5 m); goal at 1.75 m;
- **gap**: the corridor preset's geometry (0.25 m walls centred on a vertex line, no spawn zone) at
  other widths, measured at half the wall height, played by the policy trained in it; goal 2.0 m
  along it.

Each value also gets the **prediction** of the traversability map with this robot's measured limits
(``traversability.ROBOT``): whether a path leads from the spawn to the goal.

A value is passed when the episodes' mean net progress takes the robots past the feature (``past_m``:
the question is whether it gets across, not how fast; the goal is reached too where the gait keeps its
speed). The limit is the hardest value passed: the highest step and slope, the narrowest gap. Writes
``capability.{json,md}`` (``capability_<policy>`` with ``--policy``) with every value's success rate, net
progress and the map's verdict.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import mujoco
import numpy as np
import yaml

import hsa_mjx
from benchmarks.run_info import run_info, write_result
from hsa_mjx.config import BACKENDS
from hsa_mjx.terrain import TerrainSampler, reachability, traversability
from hsa_mjx.terrain.grid import Grid


@dataclasses.dataclass(frozen=True)
class Probe:
    """One feature swept over ``values`` of ``parameter`` of terrain type ``terrain``, played by ``policy``."""

    terrain: str
    parameter: str
    unit: str
    values: tuple[float, ...]
    goal_m: float
    past_m: float  # mean net progress that means the robots got past the feature
    fixed: tuple[str, ...]  # terrain settings (``terrain.`` keys = YAML values) that place the feature
    policy: str = "rough"
    higher_is_harder: bool = True


SUCCESS_RADIUS = 0.2  # m: the env's goal.success_radius (a goal counts as reached this close)
SWEEP = tuple(i / 8 for i in range(9))  # difficulties 0, 1/8, ..., 1 of one atlas
PROBES = {
    "step": Probe(
        "flat_with_ramp",
        "height",
        "m",
        tuple(0.2 * d for d in SWEEP),
        2.0,
        1.5,  # the rise is at 1.2 m: both blocks on top
        tuple(
            f"flat_with_ramp.{kv}"
            for kv in ("direction=-x", "center=[0.72,0.5]", "length=0.2", "width=1.0", "smooth_edges=false")
        ),
    ),
    "slope": Probe(
        "flat_with_incline",
        "angle",
        "deg",
        tuple(32.0 * d for d in SWEEP),
        1.75,
        1.5,  # 0.4 m up the incline
        ("flat_with_incline.x_range=[0.61,0.73]", "flat_with_incline.y_range=[0.0,1.0]"),
    ),
    # the corridor preset's geometry (0.25 m walls centred on a vertex line, no spawn zone) at other widths,
    # played by the policy trained in it
    "gap": Probe(
        "corridor",
        "corridor_width",
        "m",
        (0.82, 0.72, 0.62, 0.52, 0.42, 0.32),
        2.0,
        1.0,  # 1 m along the corridor
        ("corridor.center=0.510204", "corridor.wall_height=0.25", "flat_spawn.enabled=false"),
        "corridor",
        False,
    ),
}


def geometry() -> dict[str, float]:
    """The robot's size at its spawn pose, from the collision geoms of the model (metres)."""
    env = hsa_mjx.make_env("flat", physics__backend="c")
    model, data = env.robot.mj_model, mujoco.MjData(env.robot.mj_model)
    data.qpos[env.index.block_z] = env.config.spawn_height
    mujoco.mj_forward(model, data)
    boxes = {"lo": [], "hi": []}
    units = {"lo": [], "hi": []}
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == 0 or not (model.geom_contype[g] or model.geom_conaffinity[g]):
            continue
        rot, size = np.abs(data.geom_xmat[g].reshape(3, 3)), model.geom_size[g]
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            half, part = rot @ size, boxes
        else:  # capsules and cylinders along their local z
            half, part = rot[:, 2] * size[1] + size[0], units
        part["lo"].append(data.geom_xpos[g] - half)
        part["hi"].append(data.geom_xpos[g] + half)
    b_lo, b_hi = np.min(boxes["lo"], axis=0), np.max(boxes["hi"], axis=0)
    u_lo, u_hi = np.min(units["lo"], axis=0), np.max(units["hi"], axis=0)
    return {
        "length_m": round(float(max(b_hi[0], u_hi[0]) - min(b_lo[0], u_lo[0])), 3),
        "block_width_m": round(float(b_hi[1] - b_lo[1]), 3),
        "full_width_m": round(float(max(b_hi[1], u_hi[1]) - min(b_lo[1], u_lo[1])), 3),
        "block_height_m": round(float(b_hi[2] - b_lo[2]), 3),
        "units_underside_above_ground_m": round(float(u_lo[2] - b_lo[2]), 3),
    }


def _evaluate(
    args: argparse.Namespace, probe: Probe, levels: tuple[float, ...], extra: Sequence[str], out: Path
) -> list[dict]:
    """Rows of one terrain evaluation (``train.episodes.play.evaluate`` per type and difficulty) of ``probe``."""
    from train.config import parse_assignment
    from train.episodes.play import EvalSpec, evaluate

    overrides = dict(parse_assignment(f"env.terrain.{o}") for o in (*probe.fixed, *extra))
    spec = EvalSpec(
        policy=args.policy or probe.policy,
        backend=args.backend,
        episodes=args.episodes,
        steps=args.steps,
        seed=args.seed,
        terrain_types=(probe.terrain,),
        levels=levels,
        goal_range=(probe.goal_m, probe.goal_m),
        out=str(out),
        overrides={"env.goal.radial_bearing_deg": [0, 0], **overrides},
    )
    return evaluate(spec)["rows"]


def sweep(args: argparse.Namespace, name: str, work: Path) -> list[dict[str, Any]]:
    """Success rate and net progress at each of the probe's values."""
    probe = PROBES[name]
    if probe.terrain == "corridor":  # the width is no difficulty parameter: one evaluation per width
        rows = [
            _evaluate(args, probe, (1.0,), [f"corridor.{probe.parameter}={v}"], work / f"{name}_{v}")[0]
            for v in probe.values
        ]
    else:  # the parameter at its top value, the values as the difficulties of one atlas
        top = f"{probe.terrain}.{probe.parameter}={max(probe.values)}"
        rows = _evaluate(args, probe, tuple(SWEEP), [top], work / name)
    return [
        {
            probe.parameter: round(value, 4),
            "success_rate": row["success_rate"],
            "mean_progress_m": round(row["mean_progress_m"], 3),
            "episodes": row["episodes"],
            "ended_by": row["ended_by"],
            "map_predicts_pass": predicted_pass(probe, value),
        }
        for value, row in zip(probe.values, rows)
    ]


def predicted_pass(probe: Probe, value: float) -> bool:
    """Whether the traversability map (``traversability.ROBOT``) of the probe's tile at ``value`` has a path
    from the spawn to a cell within the success radius of the goal: the analysis the simulation checks."""
    settings = {k: yaml.safe_load(v) for k, v in (o.split("=", 1) for o in probe.fixed)}
    settings[f"{probe.terrain}.{probe.parameter}"] = value
    config = hsa_mjx.build_config(
        "flat", scene="terrain", terrain__types=[probe.terrain], **{"terrain__" + k.replace(".", "__"): v
                                                                   for k, v in settings.items()}
    )  # fmt: skip
    grid = Grid()
    data = TerrainSampler(config.terrain, grid).type_data(0, jax.random.PRNGKey(0), 1.0)
    field = np.asarray(reachability.spawn_field(data, grid, traversability.ROBOT))
    centres = reachability.cell_centres(grid, traversability.ROBOT.resolution)
    near_goal = np.hypot(centres[..., 0] - probe.goal_m, centres[..., 1]) <= SUCCESS_RADIUS
    return bool(np.isfinite(field[near_goal]).any())


def passed(probe: Probe, row: dict[str, Any]) -> bool:
    """Whether the episodes of ``row`` got past the probe's feature on average."""
    return row["mean_progress_m"] >= probe.past_m


def limit(probe: Probe, rows: list[dict[str, Any]]) -> float | None:
    """The hardest value passed: the highest step or slope, the narrowest gap (None: none passed)."""
    values = [row[probe.parameter] for row in rows if passed(probe, row)]
    if not values:
        return None
    return max(values) if probe.higher_is_harder else min(values)


def markdown(result: dict[str, Any]) -> str:
    """The result as tables: the geometry, then each probe's values and the limit found."""
    geo = result["geometry"]
    lines = [
        f"# What the robot passes ({result['physics']})",
        "",
        f"{result['date']}, {result['cpu']}; command `{result['command']}`; policies {result['policy']}; "
        f"{result['episodes']} episodes a value, passed when their mean net progress takes them past the feature; "
        "`map` is whether the traversability map (`traversability.ROBOT`) has a path to the goal.",
        "",
        "| geometry | m |",
        "| --- | --- |",
        *(f"| {k.removesuffix('_m').replace('_', ' ')} | {v:.3f} |" for k, v in geo.items()),
        "",
        "| probe | limit | map agrees |",
        "| --- | --- | --- |",
    ]
    measured = {name: probe for name, probe in PROBES.items() if name in result["probes"]}  # --probes: a subset
    for name, probe in measured.items():
        found = result["limits"][name]
        shown = "none" if found is None else f"{found:g} {probe.unit}"
        rows = result["probes"][name]
        agree = sum(passed(probe, r) == r["map_predicts_pass"] for r in rows)
        lines.append(f"| {name} | {shown} | {agree} of {len(rows)} values |")
    for name, probe in measured.items():
        title = f"## {name} ({probe.terrain}.{probe.parameter}, {probe.unit})"
        columns = f"| {probe.parameter} | success | net progress m | past at m | goal m | map |"
        lines += ["", title, "", columns, "| --- | --- | --- | --- | --- | --- |"]
        for row in result["probes"][name]:
            lines.append(
                f"| {row[probe.parameter]:g} | {row['success_rate']:.0%} | {row['mean_progress_m']:.2f} | "
                f"{probe.past_m:g} | {probe.goal_m:g} | {'pass' if row['map_predicts_pass'] else 'blocked'} |"
            )
    return "\n".join(lines) + "\n"


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--policy",
        default=None,
        help="a policy under policies/ or a policy directory for every probe (default: rough for the step and "
        "the slope, corridor for the gap)",
    )
    p.add_argument("--episodes", type=int, default=4, help="episodes per value (default 4)")
    p.add_argument("--steps", type=int, default=2000, help="steps per episode (default 2000: 40 s)")
    p.add_argument(
        "--backend", default="c", choices=BACKENDS, help="physics (default c: C MuJoCo on the CPU; or jax, warp)"
    )
    p.add_argument("--probes", default=",".join(PROBES), help=f"comma list of {list(PROBES)}")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/capability"))
    args = p.parse_args(argv)
    args.probes = [n for n in args.probes.split(",") if n]
    unknown = [n for n in args.probes if n not in PROBES]
    if unknown or not args.probes:
        p.error(f"--probes: unknown {unknown or args.probes}; choose from {list(PROBES)}")
    if args.episodes < 1 or args.steps < 1:
        p.error("--episodes and --steps must be >= 1")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    geo = geometry()
    result: dict[str, Any] = {
        **run_info(),
        "policy": args.policy or {name: probe.policy for name, probe in PROBES.items()},
        "physics": "c_mujoco" if args.backend == "c" else f"mjx_{args.backend}",
        "episodes": args.episodes,
        "max_steps": args.steps,
        "geometry": geo,
        "probes": {},
        "limits": {},
    }
    with tempfile.TemporaryDirectory() as work:
        for name in args.probes:
            result["probes"][name] = sweep(args, name, Path(work))
            result["limits"][name] = limit(PROBES[name], result["probes"][name])
            print(f"{name}: limit {result['limits'][name]} {PROBES[name].unit}", flush=True)
    name = "capability" + (f"_{Path(args.policy).name}" if args.policy else "")
    write_result(args.out / name, result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Evaluate a trained run or a shipped policy on the device.

``python -m train.evaluate RUN_DIR [--episodes N] [--checkpoint STEP] [--video]``: loads the run's config and
latest checkpoint (or the one ``--checkpoint`` names) and runs N episodes at once with the deterministic
policy (its mean action; ``--stochastic`` samples as in training; each env plays exactly one episode).
``python -m train.evaluate --policy NAME_OR_DIR [--episodes N] [--video]``: the same for a policy
directory (``policies/<NAME>`` or a path; ``hsa_mjx/deploy/policy_file.py``), its env rebuilt from its
``policy.json`` and its network run from its ``policy.npz``; defaults sized for a CPU (4 episodes
of at most 1,000 steps).

Prints success rate, mean final distance, mean speed and how the episodes ended (termination
reasons, ``time_out`` at the env's episode limit, ``not_finished`` at a shorter step cap), and
writes eval.json, the diagnostic plots (and with ``--video`` a GIF) into ``--out`` (default
``RUN_DIR/eval/`` or ``runs/eval_<NAME>/``).

``--set env.KEY=VALUE`` (repeatable) evaluates on a changed env, e.g. goals farther than training's
(``--set env.goal.radial_range=[4.0,4.5]``); the observation cannot change.

``--terrain-types all|T1,T2 --levels 0,0.5,1``: instead, ``--episodes`` episodes per terrain type
and difficulty, printed as a table of success rate and net progress and written to
terrain_eval.json and terrain_eval.png (``train/episodes/terrain_eval.py``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from hsa_mjx.sim import gl


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line's arguments (after ``main`` chose the GL platform: the backends' list imports MuJoCo)."""
    from hsa_mjx.config import BACKENDS

    parser = argparse.ArgumentParser(
        prog="python -m train.evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dir", nargs="?", help="a run directory written by python -m train")
    parser.add_argument(
        "--policy",
        default=None,
        metavar="NAME_OR_DIR",
        help="evaluate a policy directory instead: a folder name under policies/ or a path",
    )
    parser.add_argument("--episodes", type=int, default=None, help="episodes (default 16 for a run, 4 for --policy)")
    parser.add_argument(
        "--steps",
        type=int,
        default=None,
        help="max steps per episode (default: the env's max_episode_steps for a run, at most 1,000 for --policy)",
    )
    parser.add_argument(
        "--goal-range",
        type=float,
        nargs=2,
        default=None,
        metavar=("MIN", "MAX"),
        help="radial goal distance range (default: the curriculum's target range, or "
        "the env's goal.radial_range when the curriculum is off)",
    )
    parser.add_argument(
        "--stochastic",
        action="store_true",
        help="sample actions from the policy as in training (default: its mean action; run directories only)",
    )
    parser.add_argument("--video", action="store_true", help="render the first episode to episode.gif")
    parser.add_argument("--out", default=None, help="output folder (default: RUN_DIR/eval or runs/eval_<NAME>)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="env.KEY=VALUE",
        help="evaluate on a changed env, e.g. --set env.goal.radial_range=[4.0,4.5] (repeatable; "
        "not env.observation.*)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="auto",
        help="physics to evaluate on (env.physics.backend): c, the substeps in C MuJoCo "
        "(hsa_mjx.sim.host_physics), several times faster on a CPU; jax or warp, MJX's; "
        "auto (default): c on a CPU, MJX on a GPU (Warp when installed)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=1,
        help="C MuJoCo only: play the episodes in this many processes at once (train/episodes/host_workers.py)",
    )
    parser.add_argument(
        "--terrain-types",
        default=None,
        metavar="all|T1,T2",
        help="evaluate per terrain type: 'all' (the run's types) or a list (with --levels)",
    )
    parser.add_argument(
        "--levels",
        default=None,
        metavar="D1,D2",
        help="terrain difficulties in [0, 1] to evaluate each type at (default: the run's top)",
    )
    parser.add_argument(
        "--terrain-seed",
        type=int,
        default=None,
        help="seed of the evaluation's terrain tiles (default: the run's env.terrain.seed + 1000, tiles training "
        "never drew its pool from); terrain_eval.json records it beside the training's",
    )
    parser.add_argument(
        "--tiles",
        type=int,
        default=1,
        help="tiles of each random terrain type per difficulty, drawn from --terrain-seed (default 1); each "
        "episode plays one of them, so a cell's episodes spread over this many tiles",
    )
    parser.add_argument(
        "--checkpoint",
        nargs="+",
        default=None,
        metavar="STEP_OR_DIR",
        help="a run's checkpoint to evaluate: a step it saved (e.g. 26214400) or a checkpoint directory "
        "(default: the newest readable one); several: each into --out DIR/<checkpoint folder>/, all played "
        "in one batch on the same goals and tiles (mean action: train/episodes/checkpoint_batch.py)",
    )
    parser.add_argument(
        "--video-cell",
        default=None,
        metavar="TYPE:LEVEL",
        help="with --terrain-types and --video: the cell whose first episode is rendered (default: the first "
        "type at the top level)",
    )
    parser.add_argument(
        "--stuck-window-s",
        type=float,
        default=20.0,
        help="a time-out's mode is read over the episode's last this many seconds (default 20): stuck, lost "
        "or slow (train/episodes/failures.py)",
    )
    parser.add_argument(
        "--stuck-distance-m",
        type=float,
        default=0.1,
        help="within this distance of where it was over that window, a timed-out robot is stuck; this much "
        "farther, lost; this much closer, slow (default 0.1 m)",
    )
    return parser.parse_args(argv)


def spec_from_args(args: argparse.Namespace) -> Any:
    """The flags as a typed :class:`EvalSpec`: ``--set`` items as a mapping, ``--levels`` and
    ``--terrain-types`` as tuples (ValueError naming a bad one)."""
    from .config import parse_assignment
    from .episodes.play import EvalSpec

    fields = dict(vars(args))
    fields["checkpoint"] = args.checkpoint[0] if args.checkpoint and len(args.checkpoint) == 1 else None
    fields["goal_range"] = tuple(args.goal_range) if args.goal_range else None
    fields["overrides"] = dict(parse_assignment(item) for item in args.overrides)
    if args.levels is not None:
        try:
            fields["levels"] = tuple(float(v) for v in args.levels.split(","))
        except ValueError as err:
            raise ValueError(f"--levels must be comma-separated numbers in [0, 1], got {args.levels!r}") from err
    if args.video_cell is not None:
        name, _, level = args.video_cell.partition(":")
        try:
            fields["video_cell"] = (name.strip(), float(level))
        except ValueError as err:
            raise ValueError(f"--video-cell must be TYPE:LEVEL, e.g. stairs:1, got {args.video_cell!r}") from err
    if args.terrain_types not in (None, "all"):
        fields["terrain_types"] = tuple(t.strip() for t in args.terrain_types.split(",") if t.strip())
    return EvalSpec(**fields)


def report(result: dict) -> None:
    """Print an evaluation's figures (a table per terrain type and difficulty) and where its files went."""
    from .episodes import terrain_eval

    if "rows" in result:
        print(terrain_eval.table(result["rows"]))
    else:
        for key, value in result.items():
            if key not in ("files", "source"):
                print(f"{key}: {value:.4g}" if isinstance(value, float) else f"{key}: {value}")
    files = result["files"]
    print(f"wrote {len(files)} files" + (f" to {Path(files[0]).parent}" if files else ""))


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m train.evaluate`` (and ``hsa-evaluate``).

    MuJoCo fixes its OpenGL platform when it is first imported, so the offscreen platform for
    ``--video`` is chosen here, before the evaluation (which imports MuJoCo) is.
    """
    gl.choose_platform()
    args = parse_args(argv)
    from .episodes.checkpoint_batch import evaluate_many
    from .episodes.play import evaluate

    several = args.checkpoint if args.checkpoint and len(args.checkpoint) > 1 else None
    try:
        spec = spec_from_args(args)
        results = evaluate_many(spec, several) if several else [evaluate(spec)]
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for result in results:
        report(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())

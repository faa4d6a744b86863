"""Command line: ``python -m train --config configs/<task>.yaml [--set key=value ...] [--run-dir DIR]
[--resume] [--init-from RUN]`` (``hsa-train`` installed).

Every problem with the config, the run directory or the checkpoint to resume is reported before
anything is compiled. Ctrl-C (or SIGTERM) finishes the current epoch, writes a checkpoint and
exits; a second Ctrl-C (more than a second after the first) stops at once.

Several hosts: start one process per host with ``--coordinator HOST:PORT --num-processes N
--process-id I`` (or the ``HSA_COORDINATOR``, ``HSA_NUM_PROCESSES``, ``HSA_PROCESS_ID`` environment
variables), or under ``srun`` / ``mpirun`` with no flag at all; see docs/scaling.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .config import CPU_CONFIG, GPU_CONFIG, TrainConfig, default_config, load
from .devices import cluster, distributed
from .run import checkpoint
from .trainer import train

DEFAULT_CONFIG = "auto"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Parse the training command line."""
    parser = argparse.ArgumentParser(
        prog="python -m train", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--config",
        default=DEFAULT_CONFIG,
        help=f"training YAML (default: {GPU_CONFIG} on a GPU, {CPU_CONFIG} otherwise)",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a config value, e.g. --set ppo.learning_rate=1e-4 (repeatable)",
    )
    parser.add_argument("--run-dir", default=None, help="output directory (default runs/<config name>-<time>)")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue from the run dir's newest readable checkpoint (later log records are dropped)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the run already in --run-dir (its checkpoints, logs and plots)",
    )
    parser.add_argument(
        "--init-from",
        default=None,
        metavar="PATH",
        help="start from the networks of another run (a run dir or checkpoint dir): "
        "sets run.init_from; fresh optimiser, curriculum and step count",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    group = parser.add_argument_group("several hosts (jax.distributed; docs/scaling.md)")
    group.add_argument(
        "--coordinator",
        default=None,
        metavar="HOST:PORT",
        help=f"process 0's address (env {cluster.ENV_VARS['coordinator']})",
    )
    group.add_argument(
        "--num-processes",
        type=int,
        default=None,
        metavar="N",
        help=f"processes (hosts) taking part (env {cluster.ENV_VARS['num_processes']})",
    )
    group.add_argument(
        "--process-id",
        type=int,
        default=None,
        metavar="I",
        help=f"this process, 0..N-1; 0 writes the run dir (env {cluster.ENV_VARS['process_id']})",
    )
    group.add_argument(
        "--requeue",
        action="store_true",
        help="SLURM: a run stopped by a signal at its job's time limit requeues the job (scontrol requeue) "
        "once its checkpoint is written",
    )
    return parser.parse_args(argv)


def resolve(args: argparse.Namespace) -> tuple[TrainConfig, Path]:
    """The validated config and run dir (a resumed run reads its own saved config by default)."""
    if args.resume and args.run_dir is None:
        raise ValueError("--resume needs --run-dir (the run to continue)")
    config_path = Path(args.config)
    if args.config == DEFAULT_CONFIG:
        config_path = Path(default_config())
        if args.resume and (Path(args.run_dir) / "config.yaml").is_file():
            config_path = Path(args.run_dir) / "config.yaml"  # a resumed run keeps its own config
    overrides = args.overrides + ([f"run.init_from={args.init_from}"] if args.init_from else [])
    config = load(config_path, overrides)
    run_dir = (
        Path(args.run_dir) if args.run_dir else Path("runs") / f"{config_path.stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    )
    return config, run_dir


def interrupted_message(run_dir: str | Path) -> str:
    """What a hard stop leaves: the newest periodic checkpoint to ``--resume`` from, or none."""
    found = checkpoint.list_checkpoints(run_dir)
    if not found:
        return f"interrupted before any checkpoint was written in {run_dir}"
    return f"interrupted hard: no checkpoint of this moment; --resume continues from {found[-1]}"


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m train`` and the ``hsa-train`` console script."""
    args = parse_args(argv)
    run_dir = args.run_dir or "the run dir"
    try:
        spec = cluster.resolve_spec(args.coordinator, args.num_processes, args.process_id)
        cluster.initialize(spec)  # before anything asks JAX for its devices
        config, run_dir = resolve(args)
        if args.resume and args.overwrite:
            raise ValueError("--resume continues the run in --run-dir and --overwrite replaces it: give one")
        summary = train(config, run_dir, resume=args.resume, quiet=args.quiet, overwrite=args.overwrite)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # during set-up or compile, or a second Ctrl-C: no checkpoint of this moment
        print(f"\n{interrupted_message(run_dir)}", file=sys.stderr)
        return 130
    if args.requeue and summary.get("interrupted") and distributed.is_main() and cluster.should_requeue():
        print(cluster.requeue(), flush=True)
    print(f"\nrun dir: {run_dir}")
    for key, value in summary.items():
        print(f"  {key}: {value:.4g}" if isinstance(value, float) else f"  {key}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

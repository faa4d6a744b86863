"""Export a run's deterministic policy: ``python -m train.export RUN_DIR --format npz|onnx [--out DIR]``.

Reads the run's latest checkpoint (or ``--checkpoint PATH``) and writes its deterministic policy,
observation normaliser included, as a policy directory (``hsa_mjx/deploy/policy_file.py`` describes the format):

- ``--format npz``: ``policy.npz`` + ``policy.json``, run with ``hsa_mjx.deploy.policy_file.load_policy`` (numpy
  only) or ``python -m train.evaluate --policy DIR``; the format of the shipped ``policies/<task>/``.
- ``--format onnx``: ``policy.onnx`` (input ``observation`` (batch, obs), output ``action``) + the
  same ``policy.json``; needs the ``onnx`` package (``pip install -e .[export]``).

Default output: ``RUN_DIR/export_<format>/``. A corrupt or incompatible run directory is refused
(exit code 2, ``error: ...``) before anything is written.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path
from typing import Any

from hsa_mjx.deploy import policy_file
from hsa_mjx.sim.model import SERVOS
from hsa_mjx.task import observation

from .config import TrainConfig, to_dict
from .learners.registry import learner_of
from .run import checkpoint, onnx_policy, saved
from .run.folder import portable

FORMATS = ("npz", "onnx")
ONNX_FILE = "policy.onnx"


def to_numpy_policy(config: TrainConfig, ts: Any, source: dict) -> policy_file.NumpyPolicy:
    """The checked :class:`NumpyPolicy` (arrays and policy.json content) of a training state."""
    learner = learner_of(config)
    params = learner.policy_arrays(config, ts, len(SERVOS))
    network = learner.network_description(config)
    meta = policy_file.describe(
        params,
        network["activation"],
        network["distribution_type"],
        network["observation_clip"],
        list(observation.observation_labels(config.env.observation)),
    )
    # the policy runs wherever it is loaded: the physics backend is picked there (the training's is in source)
    config_dict = to_dict(config)
    config_dict["env"]["physics"]["backend"] = "auto"
    meta.update(config=config_dict, source=source)
    policy_file.check(params, meta, Path(source.get("checkpoint", "")))
    return policy_file.NumpyPolicy(params=params, meta=meta)


def load_numpy_policy(run_dir: Path, checkpoint_path: Path | None = None) -> policy_file.NumpyPolicy:
    """The deterministic policy of a run's latest (or given) checkpoint, with its provenance."""
    config, path, step = saved.open_run(run_dir, checkpoint_path)
    _, ts = saved.load_training_state(config, path, observation.observation_size(config.env.observation), len(SERVOS))
    trained_on = checkpoint.read_meta(path).get("physics_backend", config.env.physics.backend)
    source = {
        "run": portable(run_dir),
        "checkpoint": portable(path),
        "step": step,
        "env_steps": step,
        "physics_backend": trained_on,
        "exported": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    return to_numpy_policy(config, ts, source)


def write(policy: policy_file.NumpyPolicy, out: Path, fmt: str) -> Path:
    """Write ``policy`` into directory ``out`` in format ``fmt`` (atomically)."""
    if fmt == "npz":
        return policy_file.save_policy(out, policy.params, policy.meta)
    model = onnx_policy.build(policy)
    return policy_file.write_directory(
        out, {ONNX_FILE: model.SerializeToString(), policy_file.META_FILE: json.dumps(policy.meta, indent=1).encode()}
    )


def check_output(out: Path, fmt: str) -> None:
    """Refuse an unusable output directory or a missing ONNX package before loading anything."""
    policy_file.check_output(out)
    if fmt == "onnx":
        try:
            import onnx  # noqa: F401  (only whether it is installed)
        except ImportError as err:
            raise ValueError("--format onnx needs the onnx package: pip install -e .[export]") from err


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line's arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m train.export", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "run_dir",
        help="a run directory written by python -m train, or a policy directory (e.g. policies/flat) to convert",
    )
    parser.add_argument("--checkpoint", default=None, help="a checkpoint directory (default: the run's latest)")
    parser.add_argument("--format", required=True, choices=FORMATS)
    parser.add_argument("--out", default=None, help="output directory (default: RUN_DIR/export_<format>)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m train.export``."""
    args = parse_args(argv)
    run_dir = Path(args.run_dir)
    out = Path(args.out) if args.out else run_dir / f"export_{args.format}"
    try:
        check_output(out, args.format)
        if (run_dir / policy_file.META_FILE).is_file():  # a policy directory: the same policy in another format
            if args.checkpoint:
                raise ValueError("--checkpoint needs a run directory; a policy directory holds one policy")
            policy = policy_file.load_policy(run_dir)
            policy.meta["source"]["converted_from"] = portable(run_dir)
        else:
            policy = load_numpy_policy(run_dir, Path(args.checkpoint) if args.checkpoint else None)
        policy.meta["source"]["command"] = " ".join(["python -m train.export", *(argv or sys.argv[1:])])
        written = write(policy, out, args.format)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    src = policy.meta["source"]
    print(
        f"exported the deterministic policy of {src['checkpoint']} ({src['env_steps']:,} env steps) "
        f"as {args.format} to {written}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``python -m hsa_mjx.deploy --policy NAME_OR_DIR``: run an exported policy in the deployment loop.

The policy (numpy ``policy.npz``, or ``--onnx`` for the folder's ``policy.onnx`` through onnxruntime) drives the
C MuJoCo model of its env at the control rate, seeing only what the robot's sensors give
(``hsa_mjx.deploy.loop``), with ``--latency-ms`` of action delay (default: the least it trained with), on the
training model or on a robot unlike it (``--friction``, ``--block-mass``, ``--hsa-stiffness``, ``--hsa-damping``,
``--servo-gain``: scales of the model's values; ``--foot-friction``, ``--foot-anisotropy``: four scales, one per foot;
``--servo-torque-limit`` in N m; values outside the valid ranges are refused). Goals: ``--goal X Y``, or
``--episodes`` goals drawn from the policy's training goal range. Prints each episode and a summary.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from hsa_mjx.deploy import loop, policy_file
from hsa_mjx.deploy.perturbation import FEET, LIMITS, ModelPerturbation, per_foot
from hsa_mjx.randomization_config import FOOT_KEYS

ONNX_FILE = "policy.onnx"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line's arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m hsa_mjx.deploy", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--policy", required=True, metavar="NAME_OR_DIR", help="a shipped policy's name or a folder")
    parser.add_argument("--onnx", action="store_true", help=f"run the folder's {ONNX_FILE} with onnxruntime")
    parser.add_argument("--goal", type=float, nargs=2, default=None, metavar=("X", "Y"), help="one goal (m)")
    parser.add_argument("--episodes", type=int, default=4, help="goals drawn from the training range (default 4)")
    parser.add_argument("--max-steps", type=int, default=None, help="control ticks per goal (default: the env's)")
    parser.add_argument(
        "--latency-ms",
        type=float,
        default=None,
        help="action delay, a whole number of ticks (default: the least the policy trained with, its robot's own)",
    )
    parser.add_argument("--realtime", action="store_true", help="tick at the control rate in wall time")
    for name, (lo, hi) in LIMITS.items():
        what = "N m, the servos' torque limit" if name == "servo_torque_limit" else "scale of the model's value"
        feet = {"nargs": FEET, "metavar": "S"} if name in FOOT_KEYS else {}
        what = f"{FEET} scales, one per foot" if feet else what
        parser.add_argument(
            f"--{name.replace('_', '-')}", type=float, default=None, help=f"{what}, in [{lo:g}, {hi:g}]", **feet
        )
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args(argv)


def load_network(directory: Path, onnx: bool):
    """``obs -> action`` for one observation: the numpy network, or the ONNX graph through onnxruntime."""
    if not onnx:
        return policy_file.load_policy(directory)
    path = directory / ONNX_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: write it with python -m train.export {directory} --format onnx")
    try:
        import onnxruntime
    except ImportError as err:
        raise ValueError("--onnx needs onnxruntime (pip install onnxruntime)") from err
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return lambda obs: session.run(None, {"observation": np.asarray(obs, np.float32)[None]})[0][0]


def goals(args: argparse.Namespace, radial_range: tuple[float, float]) -> np.ndarray:
    """The goals to drive to: ``--goal``, or ``--episodes`` at a uniform distance in the range and direction."""
    if args.goal is not None:
        return np.asarray([args.goal])
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    rng = np.random.default_rng(args.seed)
    radius = rng.uniform(*radial_range, args.episodes)
    angle = rng.uniform(0.0, 2.0 * np.pi, args.episodes)
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


def _changes(perturbation: ModelPerturbation) -> str:
    """What a perturbation changes, in words."""
    default = ModelPerturbation()
    changed = {k: getattr(perturbation, k) for k in LIMITS if getattr(perturbation, k) != getattr(default, k)}

    def words(name: str, value) -> str:
        if name == "servo_torque_limit":
            return f"{name} {value:g} N m"
        return f"{name} x{per_foot(value)}" if name in FOOT_KEYS else f"{name} x{value:g}"

    return ", ".join(words(k, v) for k, v in changed.items())


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m hsa_mjx.deploy``."""
    args = parse_args(argv)
    try:
        directory = policy_file.locate(args.policy)
        meta = policy_file.read_meta(directory)
        network = load_network(directory, args.onnx)
        config, labels, goal_range = loop.policy_env(meta)
        own = config.randomization.latency_steps[0]  # a robot profile's latency (dfr05sr: one PWM frame)
        latency = own if args.latency_ms is None else loop.latency_steps(args.latency_ms, config.dt)
        targets = goals(args, goal_range)
        perturbation = ModelPerturbation(**{k: getattr(args, k) for k in LIMITS if getattr(args, k) is not None})
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    mj_model, index = loop.load_model(config)
    max_steps = args.max_steps or config.termination.max_episode_steps
    results = []
    for goal in targets:
        controller = loop.Controller(network, labels, config, int(meta["action"]["size"]), latency)
        robot = loop.SimulatedRobot(mj_model, index, config, realtime=args.realtime, perturbation=perturbation)
        result = loop.run(controller, robot, goal, max_steps, config.goal.success_radius)
        results.append(result)
        print(
            f"goal ({goal[0]:+.2f}, {goal[1]:+.2f}) m: {'reached' if result['reached'] else 'not reached'} after "
            f"{result['seconds']:.1f} s, {result['start_distance']:.2f} -> {result['final_distance']:.2f} m"
        )
    reached = sum(r["reached"] for r in results)
    model = "the training model" if perturbation.nominal else f"a robot with {_changes(perturbation)}"
    print(
        f"{reached} of {len(results)} goals reached ({'onnx' if args.onnx else 'numpy'} policy, "
        f"latency {latency} ticks of {config.dt * 1000:g} ms, C MuJoCo, {model})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

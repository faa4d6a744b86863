"""``python -m hsa_mjx.sysid``: identify a robot's servos from a log taken on the lifted robot.

    signal  the test signal to play (chirps of 0.1-10 Hz at several amplitudes, then steps), as a CSV
            of targets per control tick: play it on the robot held in the air (both blocks held, each
            servo driving its HSA) and log each tick's measured angles beside the targets
    synth   the log the simulator makes of that signal with a profile's servo, read by a tracker with
            noise and latency (what a real log looks like, with known figures to recover)
    fit     fit the profile's servo figures to a log (CMA-ES over C MuJoCo rollouts of the rig, then
            Levenberg-Marquardt steps), and write a profile file with them: use it as ``env.robot: PATH``

The CSV format: ``hsa_mjx.sysid.logs``; an example log: ``robots/example_log.csv``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import yaml

from hsa_mjx.config import EnvConfig, get_preset, with_overrides
from hsa_mjx.robots import load_profile
from hsa_mjx.sysid import fit as fitting
from hsa_mjx.sysid.logs import ServoLog, read_log, write_log
from hsa_mjx.sysid.rig import synthesize
from hsa_mjx.sysid.signals import SignalSpec, test_signal


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line's arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m hsa_mjx.sysid", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True)
    for name in ("signal", "synth", "fit"):
        sub = commands.add_parser(name)
        sub.add_argument("--robot", default="dfr05sr", help="the robot profile (a shipped name or a file)")
        sub.add_argument("--set", action="append", default=[], metavar="servo.KEY=VALUE", help="a servo figure")
        if name == "fit":
            sub.add_argument("log", help="the log CSV (targets and measured angles)")
            sub.add_argument("--generations", type=int, default=60)
            sub.add_argument("--population", type=int, default=12)
            sub.add_argument("--workers", type=int, default=None, help="processes (default: one per core)")
            sub.add_argument("--seed", type=int, default=0)
        else:
            sub.add_argument("--seconds", type=float, default=None, help="the test signal's first SECONDS only")
            sub.add_argument("--signal", default=None, help="synth: the signal CSV (default: the test signal)")
            sub.add_argument("--noise", type=float, default=0.005, help="synth: tracker noise, rad (Gaussian)")
            sub.add_argument("--latency-ms", type=float, default=20.0, help="synth: tracker latency")
            sub.add_argument("--seed", type=int, default=0)
        sub.add_argument("--out", required=True, help="the file to write (CSV; fit: the profile YAML)")
    return parser.parse_args(argv)


def robot_config(robot: str, settings: list[str]) -> EnvConfig:
    """The flat env of profile ``robot`` with ``servo.KEY=VALUE`` settings (ValueError for other keys)."""
    overrides = {}
    for item in settings:
        key, sep, value = item.partition("=")
        if not sep or not key.startswith("servo."):
            raise ValueError(f"--set takes servo.KEY=VALUE, got {item!r}")
        overrides[key] = yaml.safe_load(value)
    return with_overrides(get_preset("flat"), robot=robot, **overrides)


def first_seconds(signal: ServoLog, args: argparse.Namespace) -> ServoLog:
    """The signal's first ``--seconds`` (all of it without the option)."""
    if args.seconds is None:
        return signal
    if not args.seconds > 0:
        raise ValueError(f"--seconds must be > 0, got {args.seconds}")
    return dataclasses.replace(signal, targets=signal.targets[: max(2, int(round(args.seconds / signal.dt)))])


def write_profile(path: Path, robot: str, result: fitting.FitResult, log_path: str) -> None:
    """The fitted profile: ``robot``'s, its servo figures replaced by the fit's, with the fit's report."""
    profile = load_profile(robot)
    servo = {k: v for k, v in dataclasses.asdict(result.servo).items() if v or k == "model"}
    fitted = f"fit to {log_path} (python -m hsa_mjx.sysid fit)"
    sources = {**profile.sources, **{f"servo.{k}": fitted for k in servo if k != "model"}}
    report = {
        "log": log_path,
        "rms_error_rad": result.loss**0.5,
        "latency_s": result.latency_s,
        "generations": result.generations,
        "bound_95": result.bound,
        "not_identifiable": [n for n in result.bound if not result.identifiable(n)],
        "held_pull": result.held,
    }
    data = {
        "description": f"{profile.description} (servo figures fitted to {Path(log_path).name})",
        "hardware": profile.hardware,
        "sources": sources,
        "identification": report,
        "env": {**profile.env, "servo": servo},
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        f"# Fitted by python -m hsa_mjx.sysid fit from {log_path}\n" + yaml.safe_dump(data, sort_keys=False)
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m hsa_mjx.sysid``."""
    args = parse_args(argv)
    try:
        config = robot_config(args.robot, args.set)
        out = Path(args.out)
        if args.command == "signal":
            write_log(out, first_seconds(test_signal(SignalSpec(), config.dt, config.control.servo_target_limit), args))
        elif args.command == "synth":
            signal = read_log(args.signal, need_angles=False) if args.signal else None
            signal = signal or test_signal(SignalSpec(), config.dt, config.control.servo_target_limit)
            log, _ = synthesize(config, first_seconds(signal, args), args.noise, args.latency_ms / 1000.0, args.seed)
            write_log(out, log)
        else:
            log = read_log(args.log)
            start = time.perf_counter()

            def progress(generation: int, loss: float, sigma: float) -> None:
                print(f"generation {generation}: rms {loss**0.5:.5f} rad, step {sigma:.4f}", flush=True)

            result = fitting.fit(config, log, args.generations, args.population, args.seed, args.workers, progress)
            write_profile(out, args.robot, result, args.log)
            print(json.dumps({"seconds": round(time.perf_counter() - start, 1), **dataclasses.asdict(result.servo)}))
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

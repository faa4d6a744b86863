"""Does the servo fit recover known figures? ``python -m benchmarks.robots.sysid_recovery``.

For each robot profile: a "true" servo (the profile's figures moved by ``TRUTH`` factors, so the fit
does not start at the answer), its 60 s log made by the rig (``hsa_mjx.sysid synth``: tracker noise
and latency), then the fit from the profile's own figures (``hsa_mjx.sysid fit``). Each figure's
relative error (``rel_error``; the absolute error where the truth is 0), the fit's own 95 % bound on
it and whether the log pins it down, and the recovered latency go to ``--out`` (JSON and Markdown), each
row with its run's provenance. ``--robots R --merge`` fits some profiles and keeps the other rows of
``--out``; ``--merge-from FILE ...`` fits nothing and puts the rows of other runs' files into ``--out``
(profiles fitted at once in separate processes, each into its own file): the profiles can be fitted in
separate runs (38-41 min a profile on 2 cores, and about 10 min
more for each figure's error profile).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from benchmarks.run_info import report, row_provenance, run_info
from hsa_mjx.config import get_preset, with_overrides
from hsa_mjx.sysid import fit as fitting
from hsa_mjx.sysid.rig import synthesize
from hsa_mjx.sysid.signals import SignalSpec, test_signal

RESULTS = Path(__file__).resolve().parents[1] / "results" / "robots"
ROBOTS = ("dfr05sr", "xl330_m288", "st3215")  # the hardware profiles: both DC-motor servo models
TRUTH = {  # the true servo: each fitted figure times this (the dead band too, where the profile has one)
    "stall_torque": 1.15,
    "no_load_speed": 0.85,
    "gain": 1.2,
    "deadband": 1.25,
    "damping": 1.3,
    "friction": 0.8,
    "armature": 1.25,
}
PASS = 0.05  # the relative error an identifiable figure must stay within


def truth_servo(start):
    """The profile's servo (at its supply voltage) with each figure moved by ``TRUTH``."""
    servo = fitting.at_supply(start)
    moved = {}
    for name, factor in TRUTH.items():
        key = fitting.gain_key(servo.model) if name == "gain" else name
        moved[key] = fitting.figure(servo, name) * factor
    return dataclasses.replace(servo, **moved)


def rig_log(robot: str, noise: float, latency_s: float, seed: int) -> tuple:
    """(the profile's env config, the true env config, the true servo's log on the rig): the same for a seed."""
    config = with_overrides(get_preset("flat"), robot=robot)
    truth = dataclasses.replace(config, servo=truth_servo(config.servo))
    signal = test_signal(SignalSpec(), config.dt, config.control.servo_target_limit)
    log, _ = synthesize(truth, signal, noise, latency_s, seed)
    return config, truth, log


def recover(robot: str, args: argparse.Namespace) -> dict:
    """One profile's row: the true and fitted figures, their errors and sensitivities."""
    config, truth, log = rig_log(robot, args.noise, args.latency_ms / 1000.0, args.seed)
    start = time.perf_counter()
    result = fitting.fit(config, log, args.generations, args.population, args.seed, args.workers)
    rows = {}
    for name in fitting.FITTED:
        true, fitted = fitting.figure(truth.servo, name), fitting.figure(result.servo, name)
        error = abs(fitted - true) / true if true else abs(fitted - true)
        rows[name] = {
            "true": true,
            "start": fitting.figure(fitting.at_supply(config.servo), name),
            "fitted": fitted,
            "rel_error" if true else "abs_error": error,
            "bound_95": result.bound[name],
            "identifiable": result.identifiable(name),
        }
    held = {
        name: {"value": getattr(result.servo, name), "pull_of_50_percent": result.held[name]} for name in fitting.HELD
    }
    passed = all(r.get("rel_error", r.get("abs_error")) <= PASS for r in rows.values() if r["identifiable"])
    row = {
        "robot": robot,
        "model": config.servo.model,
        "log_seconds": log.seconds,
        "rms_error_rad": result.loss**0.5,
        "noise_rad": args.noise,
        "latency_s": {"true": args.latency_ms / 1000.0, "fitted": result.latency_s},
        "generations": result.generations,
        "fit_seconds": round(time.perf_counter() - start, 1),
        "figures": rows,
        "held": held,
        "passed": passed,
    }
    return {**row, **diagnosis(row, config, log, truth.servo)}


def motor_damping(figures: dict, which: str) -> float:
    """The torque per unit of joint speed the log sees in any unsaturated motion: the motor's back-EMF
    slope (stall torque / no-load speed) plus the viscous damping (N m s/rad)."""
    return figures["stall_torque"][which] / figures["no_load_speed"][which] + figures["damping"][which]


def fitted_servo(config, figures: dict):
    """The profile's servo at its supply voltage with a row's fitted figures."""
    start = fitting.at_supply(config.servo)
    values = {(fitting.gain_key(start.model) if n == "gain" else n): r["fitted"] for n, r in figures.items()}
    return dataclasses.replace(start, **values)


def _diagnosis_inputs(row: dict, seed: int) -> tuple:
    config, truth, log = rig_log(row["robot"], row["noise_rad"], row["latency_s"]["true"], seed)
    return config, log, truth.servo


def diagnosis(row: dict, config, log, truth) -> dict:
    """What separates a failed figure from an unidentifiable one: the rms error at the true figures beside
    the fit's (lower at the truth: the search stopped short), and the motor damping the two share."""
    truth_loss, fit_loss = (
        s[0] for s in fitting.Evaluator(config, log, 1)([truth, fitted_servo(config, row["figures"])])
    )
    true, fitted = motor_damping(row["figures"], "true"), motor_damping(row["figures"], "fitted")
    return {
        "rms_at_truth_rad": truth_loss**0.5,
        "rms_at_fit_rad": fit_loss**0.5,
        "motor_damping": {"true": true, "fitted": fitted, "rel_error": abs(fitted - true) / true},
    }


def run_note(row: dict) -> str:
    """Where and how a row was fitted (rows of merged runs differ), or nothing for a row without it."""
    if "run" not in row:
        return ""
    run = row["run"]
    return f" on {run['cpu_count']} CPU cores ({run['date'][:10]}, `{run['command']}`)"


def markdown(rows: list[dict], info: dict) -> str:
    """The result as a table per profile."""
    out = [f"# Servo fit recovery ({info['date'][:10]}, {info['cpu_count']} CPU cores)", "", f"`{info['command']}`", ""]
    for row in rows:
        verdict = "every identifiable figure within 5 %" if row["passed"] else "FAILED"
        out += [
            f"## {row['robot']} ({row['model']}): {verdict}",
            f"rms error {row['rms_error_rad']:.4f} rad (noise {row['noise_rad']:g}), latency "
            f"{row['latency_s']['fitted'] * 1000:.0f} ms (true {row['latency_s']['true'] * 1000:.0f}), "
            f"{row['generations']} generations, {row['fit_seconds']:.0f} s" + run_note(row),
            "",
            "| figure | true | start | fitted | error | 95 % bound (fit's own) | identifiable |",
            "|---|---|---|---|---|---|---|",
        ]
        for name, r in row["figures"].items():
            error = f"{r['rel_error']:.1%}" if "rel_error" in r else f"{r['abs_error']:.4g} (abs)"
            out.append(
                f"| {name} | {r['true']:.4g} | {r['start']:.4g} | {r['fitted']:.4g} | {error} | "
                f"{r['bound_95']:.1%} | {'yes' if r['identifiable'] else 'no'} |"
            )
        if "motor_damping" in row:
            damping = row["motor_damping"]
            out += [
                "",
                f"rms error at the true figures {row['rms_at_truth_rad']:.5f} rad, at the fitted ones "
                f"{row['rms_at_fit_rad']:.5f} rad; motor damping (stall torque / no-load speed + damping) "
                f"{damping['true']:.4g} true, {damping['fitted']:.4g} fitted: {damping['rel_error']:.1%}",
            ]
        out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.robots.sysid_recovery``."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.robots.sysid_recovery", description=__doc__)
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS))
    parser.add_argument("--generations", type=int, default=80)
    parser.add_argument("--population", type=int, default=12)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--noise", type=float, default=0.005, help="tracker noise, rad")
    parser.add_argument("--latency-ms", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS / "sysid_recovery.json")
    parser.add_argument(
        "--merge",
        action="store_true",
        help="keep the rows of other robots already in --out (each row names its run): profiles fitted in "
        "separate runs, on one machine or several, in one file",
    )
    parser.add_argument(
        "--merge-from",
        type=Path,
        nargs="+",
        default=None,
        help="results files of other runs: their rows replace those of the same robots in --out (nothing is fitted)",
    )
    parser.add_argument(
        "--diagnose",
        type=Path,
        default=None,
        help="a finished run's JSON: add each row's diagnosis (its log made again from --seed) and write it again",
    )
    args = parser.parse_args(argv)
    if args.diagnose is not None:
        data = json.loads(args.diagnose.read_text())
        rows = [{**r, **diagnosis(r, *_diagnosis_inputs(r, args.seed))} for r in data["rows"]]
        info = {k: v for k, v in data.items() if k != "rows"}
        report(args.diagnose, {**info, "rows": rows}, markdown(rows, info))
        return 0
    if args.merge_from is not None:
        return merge_files(args.out, args.merge_from)
    info = run_info()
    rows = kept_rows(args.out, args.robots) if args.merge else []
    for robot in args.robots:  # the files written again after each profile: a long run keeps what it has
        row = {**recover(robot, args), "run": {**row_provenance(info), "cpu_count": info["cpu_count"]}}
        rows = merged(rows, row)
        print(f"{robot}: passed {row['passed']}", flush=True)
        report(args.out, {**info, "rows": rows}, markdown(rows, info))
    return 0 if all(r["passed"] for r in rows) else 1


def kept_rows(out: Path, robots: list[str]) -> list[dict]:
    """``--merge``: the rows of ``out`` (if it exists) for robots other than ``robots``."""
    if not out.is_file():
        return []
    return [row for row in json.loads(out.read_text())["rows"] if row["robot"] not in robots]


def merge_files(out: Path, paths: list[Path]) -> int:
    """``--merge-from``: the rows of ``paths`` into ``out`` (each row keeps its run); 0 if every row passed.
    FileNotFoundError naming a missing file."""
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"no results file at {missing}")
    rows = json.loads(out.read_text())["rows"] if out.is_file() else []
    for path in paths:
        for row in json.loads(path.read_text())["rows"]:
            rows = merged(rows, row)
    info = run_info()
    report(out, {**info, "rows": rows}, markdown(rows, info))
    return 0 if all(r["passed"] for r in rows) else 1


def merged(rows: list[dict], row: dict) -> list[dict]:
    """``rows`` with ``row`` in place of any of its robot, in ``ROBOTS`` order (others last)."""
    rows = [r for r in rows if r["robot"] != row["robot"]] + [row]
    return sorted(rows, key=lambda r: ROBOTS.index(r["robot"]) if r["robot"] in ROBOTS else len(ROBOTS))


if __name__ == "__main__":
    sys.exit(main())

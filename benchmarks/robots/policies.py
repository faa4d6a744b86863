"""Each hardware profile's policies on its own task: its own flat policy, the family policy, MJX and C MuJoCo.

    python -m benchmarks.robots.policies [--sweep benchmarks/sweeps/hardware_profiles.yaml] [--sweep-dir DIR]
        [--backend auto|jax|warp|c] [--workers K] [--report-only] [--out benchmarks/results/robots]

The runs are a sweep's (``benchmarks.sweeps.run``): its arms named after a robot profile (``hsa_mjx.robots``)
are that profile's own policies, an arm whose config draws robots per env (``randomization.robots``) is a
family policy over them. Each evaluation plays the run's final checkpoint with its mean action on the
sweep's goals (``evaluate.episodes`` from ``evaluate.seed``) in the profile's task (its own config's goal
range), and lands in ``RUN/profile_eval/<profile>_<backend>/eval.json`` (skipped when it played the run's
final checkpoint):

- a family run on each profile alone: ``randomization.robot_weights`` one-hot (the observation it trained
  on stays), the profile's latency;
- an own run on C MuJoCo (``--backend c``); on MJX its figure is the sweep's own evaluation (``sweep_eval``).

The report, one ``policies_<profile>.json`` per profile and ``policies.md``: each policy on each physics
pooled over its seeds (Wilson 95 % interval, each seed's figure) and the checks: the own policy reaches
``TARGET`` of goals on MJX, the family policy is within ``POINTS`` of it (on MJX, and on C MuJoCo), C MuJoCo
within ``POINTS`` of MJX on the seeds both played (each a difference with Newcombe's interval; a check passes
on the difference, the interval beside).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from benchmarks.run_info import run_info
from benchmarks.stats import difference_interval, wilson_interval
from benchmarks.sweeps import report as sweep_report
from benchmarks.sweeps import run as sweeps
from benchmarks.sweeps.grid import read_json
from hsa_mjx.robots import profile_names
from train import config as train_config
from train.episodes.policy_sources import default_goal_range

SWEEP = "benchmarks/sweeps/hardware_profiles.yaml"
OUT = Path("benchmarks/results/robots")
TARGET = 0.9  # the own policy's share of goals
POINTS = 0.05  # the family against the own policy, C MuJoCo against MJX
MJX = ("auto", "jax", "warp")


def roles(sweep: sweeps.Sweep) -> tuple[list[str], list[str]]:
    """(the arms named after a profile, the arms whose config draws robots per env: family policies)."""
    config = {arm: train_config.load(sweep.config_of(arm), sweep.overrides(arm, sweep.seeds[0])) for arm in sweep.arms}
    profiles = [arm for arm in sweep.arms if arm in profile_names()]
    families = [arm for arm in sweep.arms if config[arm].env.randomization.robots]
    if not profiles:
        raise ValueError(f"sweep {sweep.name!r} has no arm named after a robot profile ({profile_names()})")
    return profiles, families


def task(sweep: sweeps.Sweep, profile: str) -> dict[str, Any]:
    """A profile's task, from its own arm's config: the goal range and the latency."""
    config = train_config.load(sweep.config_of(profile), sweep.overrides(profile, sweep.seeds[0]))
    lo, hi = default_goal_range(config)
    return {
        "config": sweep.config_of(profile),
        "goal_range": [lo, hi],
        "latency_steps": list(config.env.randomization.latency_steps),
    }


def profile_overrides(sweep: sweeps.Sweep, family: str, profile: str) -> list[str]:
    """``--set`` items that play family run ``family`` on ``profile`` alone, in the profile's latency."""
    config = train_config.load(sweep.config_of(family), sweep.overrides(family, sweep.seeds[0]))
    robots = config.env.randomization.robots
    if profile not in robots:
        raise ValueError(f"arm {family!r} draws {list(robots)}, not {profile!r}")
    weights = [1 if name == profile else 0 for name in robots]
    lo, hi = task(sweep, profile)["latency_steps"]
    return [
        f"env.randomization.robot_weights=[{','.join(map(str, weights))}]",
        f"env.randomization.latency_steps=[{lo},{hi}]",
    ]


def eval_dir(run_dir: Path, profile: str, backend: str, own: bool) -> Path:
    """Where one evaluation lives: an own run's on MJX is the sweep's."""
    if own and backend in MJX:
        return run_dir / "sweep_eval"
    return run_dir / "profile_eval" / f"{profile}_{'c' if backend == 'c' else 'mjx'}"


def commands(sweep: sweeps.Sweep, out: Path, backend: str, workers: int) -> list[tuple[Path, list[str]]]:
    """(folder, ``python -m train.evaluate`` arguments) of each evaluation still to play."""
    profiles, families = roles(sweep)
    ev, todo = sweep.evaluate, []
    for job in sweeps.plan(sweep, out):
        owned = [job.arm] if job.arm in profiles else profiles if job.arm in families else []
        for profile in owned:
            folder = eval_dir(job.run_dir, profile, backend, own=job.arm == profile)
            if sweep_report.is_current(folder, job.run_dir) or not sweeps.trained(job, sweep.env_steps):
                continue
            args = [str(job.run_dir), "--out", str(folder), "--seed", str(ev.get("seed", 1000)), "--backend", backend]
            args += ["--episodes", str(ev.get("episodes", 128))]
            args += ["--goal-range", *(str(v) for v in task(sweep, profile)["goal_range"])]
            for item in profile_overrides(sweep, job.arm, profile) if job.arm != profile else []:
                args += ["--set", item]
            args += ["--workers", str(workers)] if backend == "c" else []
            todo.append((folder, args))
    return todo


def pooled(folders: list[tuple[int, Path]]) -> dict[str, Any] | None:
    """The evaluations in ``folders`` ((seed, folder)) pooled: successes, interval, each seed's figures."""
    done = [(seed, read_json(folder / "eval.json")) for seed, folder in folders]
    done = [(seed, e) for seed, e in done if e]
    if not done:
        return None
    successes = sum(round(e["success_rate"] * e["episodes"]) for _, e in done)
    episodes = sum(int(e["episodes"]) for _, e in done)
    return {
        "seeds": [seed for seed, _ in done],
        "successes": int(successes),
        "episodes": episodes,
        "success_rate": successes / episodes,
        "ci95": list(wilson_interval(int(successes), episodes)),
        "per_seed": {
            str(seed): {
                k: e.get(k) for k in ("success_rate", "mean_speed_m_per_s", "time_out", "success_by_goal_bearing")
            }
            for seed, e in done
        },
        "physics": sorted({e.get("physics") for _, e in done}),
    }


def check(first: dict | None, second: dict | None, within: float) -> dict[str, Any] | None:
    """``first`` minus ``second`` with Newcombe's interval; passed when the difference is within ``within``."""
    if not first or not second:
        return None
    d, low, high = difference_interval(
        (first["successes"], second["successes"]), (first["episodes"], second["episodes"])
    )
    return {"difference": d, "ci95": [low, high], "within": within, "passed": abs(d) <= within}


def report(sweep: sweeps.Sweep, out: Path, profile: str, families: list[str]) -> dict[str, Any]:
    """One profile's figures and checks."""
    jobs = sweeps.plan(sweep, out)

    def figures(arm: str, backend: str, seeds: list[int] | None = None) -> dict | None:
        runs = [j for j in jobs if j.arm == arm and (seeds is None or j.seed in seeds)]
        folders = [(j.seed, eval_dir(j.run_dir, profile, backend, own=arm == profile)) for j in runs]
        return pooled([(seed, f) for (seed, f), j in zip(folders, runs) if sweep_report.is_current(f, j.run_dir)])

    own = {"mjx": figures(profile, "auto"), "c_mujoco": figures(profile, "c")}
    family = {arm: {"mjx": figures(arm, "auto"), "c_mujoco": figures(arm, "c")} for arm in families}
    mjx = own["mjx"]
    same_seeds = figures(profile, "auto", own["c_mujoco"]["seeds"]) if own["c_mujoco"] else None
    checks = {
        "own_target": {"target": TARGET, "passed": mjx["success_rate"] >= TARGET} if mjx else None,
        "two_seeds": {"seeds": len(mjx["seeds"]) if mjx else 0, "passed": bool(mjx) and len(mjx["seeds"]) >= 2},
        "c_mujoco_vs_mjx": check(own["c_mujoco"], same_seeds, POINTS),  # on the seeds both played
        **{f"{arm}_vs_own": check(family[arm]["mjx"], mjx, POINTS) for arm in families},
        **{f"{arm}_vs_own_c_mujoco": check(family[arm]["c_mujoco"], own["c_mujoco"], POINTS) for arm in families},
    }
    return {
        "profile": profile,
        "sweep": sweep.name,
        "env_steps": sweep.env_steps,
        "task": task(sweep, profile),
        "evaluation": {
            "episodes_per_run": sweep.evaluate.get("episodes"),
            "seed": sweep.evaluate.get("seed"),
            "action": "mean",
        },
        "own": own,
        "family": family,
        "checks": checks,
    }


def _rate(figures: dict | None) -> str:
    if not figures:
        return "not evaluated"
    low, high = figures["ci95"]
    seeds = ", ".join(f"{v['success_rate']:.1%}" for v in figures["per_seed"].values())
    return f"{figures['success_rate']:.1%} ({low:.0%}-{high:.0%}; seeds {seeds}; {figures['episodes']} goals)"


def _check(result: dict | None) -> str:
    if not result:
        return "not measured"
    low, high = result["ci95"]
    verdict = "passed" if result["passed"] else "failed"
    return f"{result['difference'] * 100:+.1f} points ({low * 100:+.1f} to {high * 100:+.1f}): {verdict}"


def markdown(reports: list[dict[str, Any]]) -> str:
    """One table row per profile and policy."""
    lines = [
        "# Each hardware profile's policies on its own task",
        "",
        "Mean action, the sweep's goals in the profile's task; success with its 95 % interval (Wilson) and each",
        f"seed's figure; the checks: own policy >= {TARGET:.0%} on MJX, the family and C MuJoCo within "
        f"{POINTS * 100:g} points.",
        "",
        "| profile | goals | own, MJX | own, C MuJoCo | C - MJX | family, MJX | family - own | family, C MuJoCo | "
        "family - own, C MuJoCo |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in reports:
        lo, hi = r["task"]["goal_range"]
        goals = f"{lo:g} m" if lo == hi else f"{lo:g}-{hi:g} m"
        own = f"{_rate(r['own']['mjx'])} | {_rate(r['own']['c_mujoco'])} | {_check(r['checks']['c_mujoco_vs_mjx'])}"
        for arm, family in (r["family"] or {"-": {"mjx": None, "c_mujoco": None}}).items():
            versus = f"{_rate(family['mjx'])} | {_check(r['checks'].get(f'{arm}_vs_own'))} | "
            versus += f"{_rate(family['c_mujoco'])} | {_check(r['checks'].get(f'{arm}_vs_own_c_mujoco'))}"
            lines.append(f"| {r['profile']} | {goals} | {own} | {versus} |")
    return "\n".join(lines) + "\n"


def play(todo: list[tuple[Path, list[str]]]) -> int:
    """Each evaluation in its own process, one after another; the number that failed."""
    failed = 0
    for folder, args in todo:
        folder.mkdir(parents=True, exist_ok=True)
        print(f"evaluate {folder}", flush=True)
        with open(folder.parent / f"{folder.name}.log", "w") as log:
            code = subprocess.call(
                [sys.executable, "-m", "train.evaluate", *args],
                stdout=log,
                stderr=subprocess.STDOUT,
                env=dict(os.environ, PYTHONUNBUFFERED="1"),
            )
        failed += code != 0
        print(f"  {'failed: see ' + log.name if code else 'done'}", flush=True)
    return failed


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.robots.policies``."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.robots.policies",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--sweep", default=SWEEP, help=f"the sweep file (default {SWEEP})")
    parser.add_argument("--sweep-dir", default=None, help="the sweep's output folder (default runs/sweeps/<name>)")
    parser.add_argument("--backend", choices=(*MJX, "c"), default="auto", help="the physics to evaluate on")
    parser.add_argument("--workers", type=int, default=1, help="C MuJoCo: processes per evaluation")
    parser.add_argument("--report-only", action="store_true", help="write the report from the evaluations there")
    parser.add_argument("--out", type=Path, default=OUT, help=f"the report's folder (default {OUT})")
    args = parser.parse_args(argv)
    try:
        sweep = sweeps.load(args.sweep)
        profiles, families = roles(sweep)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    runs = Path(args.sweep_dir or Path("runs") / "sweeps" / sweep.name)
    failed = 0 if args.report_only else play(commands(sweep, runs, args.backend, args.workers))
    reports = [report(sweep, runs, profile, families) for profile in profiles]
    args.out.mkdir(parents=True, exist_ok=True)
    info = {k: v for k, v in run_info().items() if k not in ("backend", "device", "device_count")}
    for r in reports:
        (args.out / f"policies_{r['profile']}.json").write_text(json.dumps({**r, "run_info": info}, indent=1))
    text = markdown(reports)
    (args.out / "policies.md").write_text(text)
    print(text)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())

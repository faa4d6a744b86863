"""Compare training recipes honestly: arms x seeds at equal env steps, each run evaluated, with intervals.

    python -m benchmarks.sweeps.run SWEEP.yaml [--out DIR] [--devices 0,1] [--time-limit S] [--report-only]

A sweep file (``benchmarks/sweeps/*.yaml``) names a question, a training config, the env steps every run
trains for, the seeds, the arms (each a list of ``--set`` overrides over the config, or a mapping
``{config: PATH, set: [...]}`` for an arm trained from a config of its own) and the evaluation.
Every (arm, seed) is one run of ``python -m train`` in ``OUT/runs/<arm>/seed<k>``, one run
per GPU at a time on a host of several (``CUDA_VISIBLE_DEVICES`` per process; in sequence on one GPU
or a CPU; a GPU named k times in ``--devices`` runs k at once, each with 1/k of XLA's memory), then
one ``python -m train.evaluate`` of its final checkpoint with the mean action: on flat ground over
``evaluate.episodes`` goals, on terrain per type at the given levels over tiles of a seed the run never
trained on. With ``evaluate.grid`` each run's policy is also exported and played over a
``benchmarks.robustness.score`` grid, and so is every ``grid.reference`` policy (a shipped name or a policy
folder): per cell, each arm pooled over its seeds and its difference to each reference, with intervals
(``benchmarks.sweeps.grid``). ``--time-limit`` sends SIGTERM to the runs still training when the time is
nearly spent (each writes a checkpoint); running the same command again resumes them and skips what
is done. Raising ``env_steps`` continues every run from its checkpoint and evaluates it again (an
evaluation of an earlier checkpoint is never reported). The report (``benchmarks.sweeps.report``):
``sweep.json``, ``sweep.md`` and one plot per arm plus ``sweep.png`` in ``OUT``; every figure with its
95 % interval, the arms against the first.

The sweep file is checked before anything runs: unknown keys, an arm whose config does not build,
a missing config file are refused with a ValueError naming them.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import jax
import yaml

from benchmarks.robustness import grids
from benchmarks.sweeps import checkpoints
from benchmarks.sweeps import report as sweep_report
from hsa_mjx.deploy import policy_file
from train import config as train_config

KEYS = ("name", "question", "config", "env_steps", "seeds", "set", "arms", "evaluate", "target_success", "budget_s")
EVALUATE_KEYS = ("episodes", "steps", "goal_range", "seed", "backend", "terrain", "grid", "every_checkpoint")
GRID_KEYS = ("name", "episodes", "reference")
ARM_KEYS = ("config", "set")  # an arm given as a mapping: its own training config, its overrides
TERRAIN_KEYS = ("types", "levels", "tiles", "terrain_seed")
GRID_TAG = "grid"  # robustness_grid.json in each run's sweep_grid/
GRACE_S = 90  # --time-limit: SIGTERM this long before the limit (the epoch in flight ends, a checkpoint is written)


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A sweep file, checked."""

    name: str
    question: str
    config: str
    env_steps: int
    seeds: tuple[int, ...]
    common: tuple[str, ...]
    arms: dict[str, tuple[str, ...]]
    evaluate: dict[str, Any]
    target_success: float = 0.9
    arm_configs: dict[str, str] = dataclasses.field(default_factory=dict)  # arms trained from another config
    budget_s: float = 0.0  # > 0: every run trains this many seconds of its training clock (run.max_training_s)

    def config_of(self, arm: str) -> str:
        """The training config of one arm: its own, or the sweep's."""
        return self.arm_configs.get(arm, self.config)

    def overrides(self, arm: str, seed: int) -> list[str]:
        """The ``--set`` overrides of one run: the common ones, the arm's, its seed and length (and budget)."""
        budget = [f"run.max_training_s={self.budget_s}"] if self.budget_s > 0 else []
        return [*self.common, *self.arms[arm], f"run.seed={seed}", f"run.num_timesteps={self.env_steps}", *budget]


def _unknown(data: dict, valid: tuple[str, ...], where: str) -> None:
    unknown = sorted(set(data) - set(valid))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; valid keys: {list(valid)}")


def _check_grid(grid: Any, where: str) -> None:
    """ValueError (or FileNotFoundError for a reference policy) unless ``grid`` is None or a valid grid."""
    if grid is None:
        return
    if not isinstance(grid, dict):
        raise ValueError(f"{where}: a mapping with keys {list(GRID_KEYS)}, got {grid!r}")
    _unknown(grid, GRID_KEYS, where)
    if grid.get("name") not in grids.GRIDS:
        raise ValueError(f"{where}.name: {grid.get('name')!r}; grids: {sorted(grids.GRIDS)}")
    if int(grid.get("episodes", 1)) < 1:
        raise ValueError(f"{where}.episodes must be >= 1, got {grid['episodes']!r}")
    for policy in grid.get("reference") or ():
        policy_file.locate(policy)


def _arms(data: dict, path: Path) -> tuple[dict[str, tuple[str, ...]], dict[str, str]]:
    """Each arm's overrides, and the config of each arm given as ``{config: PATH, set: [...]}``."""
    arms, configs = {}, {}
    for name, value in data.items():
        if isinstance(value, dict):
            _unknown(value, ARM_KEYS, f"{path}: arm {name!r}")
            if "config" in value:
                configs[str(name)] = str(value["config"])
            value = value.get("set")
        arms[str(name)] = tuple(value or ())
    return arms, configs


def load(path: str | Path) -> Sweep:
    """Read and check a sweep file: every arm's config is built (and so validated) here, before any run."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"sweep file not found: {path}")
    data = yaml.safe_load(path.read_text()) or {}
    _unknown(data, KEYS, str(path))
    missing = [k for k in ("name", "config", "env_steps", "seeds", "arms", "evaluate") if k not in data]
    if missing:
        raise ValueError(f"{path}: missing key(s) {missing}")
    evaluate = dict(data["evaluate"] or {})
    _unknown(evaluate, EVALUATE_KEYS, f"{path}: evaluate")
    _unknown(evaluate.get("terrain") or {}, TERRAIN_KEYS, f"{path}: evaluate.terrain")
    _check_grid(evaluate.get("grid"), f"{path}: evaluate.grid")
    arms, arm_configs = _arms(data["arms"] or {}, path)
    seeds = tuple(int(s) for s in data["seeds"])
    if len(arms) < 1 or len(seeds) < 1 or len(set(seeds)) != len(seeds):
        raise ValueError(f"{path}: need at least one arm and distinct seeds, got arms {list(arms)}, seeds {seeds}")
    sweep = Sweep(
        name=str(data["name"]),
        question=str(data.get("question", "")),
        config=str(data["config"]),
        env_steps=int(data["env_steps"]),
        seeds=seeds,
        common=tuple(data.get("set") or ()),
        arms=arms,
        evaluate=evaluate,
        target_success=float(data.get("target_success", 0.9)),
        arm_configs=arm_configs,
        budget_s=float(data.get("budget_s", 0.0)),
    )
    for arm in arms:
        try:
            train_config.load(sweep.config_of(arm), sweep.overrides(arm, seeds[0]))
        except (ValueError, TypeError) as err:
            raise ValueError(f"{path}: arm {arm!r} does not build: {err}") from err
    return sweep


@dataclasses.dataclass
class Job:
    """One run of the sweep: its arm, seed, folder and commands."""

    arm: str
    seed: int
    run_dir: Path
    train: list[str]  # empty: a reference policy, evaluated only
    evaluate: list[str]  # empty: no evaluation at the training model
    grid: list[list[str]] = dataclasses.field(default_factory=list)  # export, then the robustness grid
    every_checkpoint: bool = False  # also evaluate each checkpoint (benchmarks.sweeps.checkpoints)

    @property
    def grid_result(self) -> Path:
        """Where the grid evaluation writes its result."""
        return self.run_dir / "sweep_grid" / f"robustness_{GRID_TAG}.json"


def evaluation_args(sweep: Sweep, run_dir: Path) -> list[str]:
    """``python -m train.evaluate``'s arguments for a run: the mean action, on unseen tiles on terrain."""
    ev = sweep.evaluate
    args = [str(run_dir), "--out", str(run_dir / "sweep_eval"), "--seed", str(ev.get("seed", 1000))]
    args += ["--episodes", str(ev.get("episodes", 128)), "--backend", str(ev.get("backend", "auto"))]
    if ev.get("steps"):
        args += ["--steps", str(ev["steps"])]
    if ev.get("goal_range"):
        args += ["--goal-range", *(str(v) for v in ev["goal_range"])]
    terrain = ev.get("terrain")
    if terrain:
        args += ["--terrain-types", str(terrain.get("types", "all")), "--levels", str(terrain.get("levels", "1"))]
        args += ["--tiles", str(terrain.get("tiles", 8)), "--terrain-seed", str(terrain.get("terrain_seed", 1000))]
    return args


def grid_args(sweep: Sweep, policy: str | Path, out: Path) -> list[str]:
    """``python -m benchmarks.robustness.score``'s arguments for one policy over the sweep's grid."""
    ev, grid = sweep.evaluate, sweep.evaluate["grid"]
    args = [str(policy), "--grid", grid["name"], "--episodes", str(grid.get("episodes", ev.get("episodes", 128)))]
    args += ["--seed", str(ev.get("seed", 1000)), "--backend", str(ev.get("backend", "auto"))]
    return ["-m", "benchmarks.robustness.score", *args, "--tag", GRID_TAG, "--out-dir", str(out / "sweep_grid")]


def grid_commands(sweep: Sweep, run_dir: Path) -> list[list[str]]:
    """A run's grid evaluation: its mean-action policy exported, then played over the grid."""
    if not sweep.evaluate.get("grid"):
        return []
    export = ["-m", "train.export", str(run_dir), "--format", "npz", "--out", str(run_dir / "export_npz")]
    return [export, grid_args(sweep, run_dir / "export_npz", run_dir)]


def references(sweep: Sweep, out: Path) -> list[Job]:
    """One job per reference policy of the grid evaluation: no training, the grid alone."""
    refs = (sweep.evaluate.get("grid") or {}).get("reference") or ()
    jobs = []
    for policy in refs:
        run_dir = out / "reference" / Path(str(policy)).name
        jobs.append(Job(f"reference {policy}", 0, run_dir, [], [], [grid_args(sweep, policy, run_dir)]))
    return jobs


def plan(sweep: Sweep, out: Path) -> list[Job]:
    """Every (arm, seed) run, seeds outermost (so that a cut-off sweep has every arm at its first seeds)."""
    jobs = []
    for seed in sweep.seeds:
        for arm in sweep.arms:
            run_dir = out / "runs" / arm / f"seed{seed}"
            train = ["-m", "train", "--config", sweep.config_of(arm), "--run-dir", str(run_dir), "--quiet"]
            for item in sweep.overrides(arm, seed):
                train += ["--set", item]
            evaluate = ["-m", "train.evaluate", *evaluation_args(sweep, run_dir)]
            every = bool(sweep.evaluate.get("every_checkpoint"))
            jobs.append(Job(arm, seed, run_dir, train, evaluate, grid_commands(sweep, run_dir), every))
    return jobs


def trained(job: Job, env_steps: int) -> bool:
    """Whether the run finished: its env steps, or its training clock's budget (its summary says so)."""
    summary = sweep_report.read_json(job.run_dir / "summary.json")
    if not summary or summary.get("interrupted"):
        return False
    return int(summary.get("env_steps", 0)) >= env_steps or summary.get("stopped_by") == "max_training_s"


class Runner:
    """Runs the jobs, one per device at a time, and stops them cleanly at the time limit."""

    def __init__(self, devices: list[str | None], deadline: float | None):
        self.devices, self.deadline, self.lock = devices, deadline, threading.Lock()
        self.running: list[subprocess.Popen] = []
        self.stopping = False

    def environment(self, device: str | None) -> dict[str, str]:
        """A run's environment on ``device``: that GPU alone and, where k runs share it (``--devices 0,0``),
        XLA's preallocation cut to 1/k of its default 75 % (``XLA_PYTHON_CLIENT_MEM_FRACTION``, unless
        set), so that k runs and their Warp buffers fit beside each other."""
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        if device is not None:
            env["CUDA_VISIBLE_DEVICES"] = device
            sharing = self.devices.count(device)
            if sharing > 1 and "XLA_PYTHON_CLIENT_MEM_FRACTION" not in os.environ:
                env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{0.75 / sharing:.3f}"
        return env

    def _call(self, args: list[str], device: str | None, log: Path) -> int:
        env = self.environment(device)
        with self.lock:
            if self.stopping:
                return -1
            with open(log, "a") as fh:
                proc = subprocess.Popen([sys.executable, *args], stdout=fh, stderr=subprocess.STDOUT, env=env)
            self.running.append(proc)
        code = proc.wait()
        with self.lock:
            self.running.remove(proc)
        return code

    def _one(self, job: Job, env_steps: int, device: str | None) -> None:
        job.run_dir.mkdir(parents=True, exist_ok=True)
        log = job.run_dir / "sweep.log"
        if job.train and not trained(job, env_steps):
            resume = ["--resume"] if (job.run_dir / "checkpoints").is_dir() else ["--overwrite"]
            print(f"[{device}] train {job.arm} seed {job.seed}", flush=True)
            if self._call(job.train + resume, device, log) != 0 or not trained(job, env_steps):
                return
            for stale in ("sweep_eval", "sweep_grid", "export_npz"):  # of an earlier checkpoint, if any
                shutil.rmtree(job.run_dir / stale, ignore_errors=True)
        if job.evaluate and not sweep_report.is_current(job.run_dir / "sweep_eval", job.run_dir):
            print(f"[{device}] evaluate {job.arm} seed {job.seed}", flush=True)
            if self._call(job.evaluate, device, log) != 0:
                shutil.rmtree(job.run_dir / "sweep_eval", ignore_errors=True)
        if job.every_checkpoint and job.evaluate:
            pending = checkpoints.pending(job.run_dir)
            for args in checkpoints.commands(job.evaluate, pending, job.run_dir):
                names = [Path(a).name for a in args[args.index("--checkpoint") + 1 :]]
                print(f"[{device}] evaluate {job.arm} seed {job.seed} {', '.join(names)}", flush=True)
                if self._call(args, device, log) == 0:
                    for path in pending:
                        if path.name in names:
                            checkpoints.write_clock(path, job.run_dir)
        if job.grid and not job.grid_result.is_file():
            print(f"[{device}] grid {job.arm} seed {job.seed}", flush=True)
            for args in job.grid:
                if self._call(args, device, log) != 0:
                    return

    def _worker(self, device: str | None, queue: list[Job], env_steps: int) -> None:
        while True:
            with self.lock:
                if not queue or self.stopping:
                    return
                job = queue.pop(0)
            self._one(job, env_steps, device)

    def run(self, jobs: list[Job], env_steps: int) -> None:
        """Every job, each device taking the next as it frees; SIGTERM to all at the deadline."""
        queue = list(jobs)
        threads = [threading.Thread(target=self._worker, args=(d, queue, env_steps)) for d in self.devices]
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            time.sleep(1.0)
            if self.deadline is not None and time.monotonic() > self.deadline - GRACE_S and not self.stopping:
                print("time limit near: stopping the runs (each writes a checkpoint)", flush=True)
                with self.lock:
                    self.stopping = True
                    for proc in self.running:
                        proc.send_signal(signal.SIGTERM)
        for t in threads:
            t.join()


def gpu_names() -> list[str]:
    """The lines of ``nvidia-smi -L`` (one per GPU of the host), or [] without one."""
    try:
        listed = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    return [line.strip() for line in listed.splitlines() if line.startswith("GPU ")]


def local_gpus() -> list[str | None]:
    """The GPUs to run on (CUDA_VISIBLE_DEVICES respected), or [None] (one CPU run at a time)."""
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    if visible:
        return [d.strip() for d in visible.split(",") if d.strip()]
    return [str(i) for i in range(len(gpu_names()))] or [None]


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.sweeps.run``."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.sweeps.run",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("sweep", help="a sweep file (benchmarks/sweeps/*.yaml)")
    parser.add_argument("--out", default=None, help="output folder (default runs/sweeps/<name>)")
    parser.add_argument(
        "--devices",
        default=None,
        help="GPU ids to use, e.g. 0,1 or 0,0,1,1 for two runs a GPU (default: every GPU listed); with "
        "--report-only, the devices the runs ran on, for the report",
    )
    parser.add_argument("--time-limit", type=float, default=None, help="seconds; stop the runs cleanly before it")
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="write the report again from the runs already there (keeping the host and date they recorded)",
    )
    args = parser.parse_args(argv)
    jax.config.update("jax_platforms", "cpu")  # this process computes nothing: the GPUs stay the runs'
    start = time.monotonic()
    try:
        sweep = load(args.sweep)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    out = Path(args.out or Path("runs") / "sweeps" / sweep.name)
    jobs, refs = plan(sweep, out), references(sweep, out)
    devices = [d.strip() for d in args.devices.split(",")] if args.devices else None
    if not args.report_only:
        devices = devices or local_gpus()
        deadline = None if args.time_limit is None else start + args.time_limit
        print(f"sweep {sweep.name}: {len(jobs)} runs of {sweep.env_steps:,} env steps on devices {devices}", flush=True)
        Runner(devices, deadline).run(jobs + refs, sweep.env_steps)
    sweep_report.write(sweep, jobs, out, gpu_names(), rewrite=args.report_only, references=refs, devices=devices)
    print((out / "sweep.md").read_text(), end="")  # the report as written: arms, runs, checkpoints, grid
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Compare training recipes honestly: arms x seeds at equal env steps, each run evaluated, with intervals.

    python -m benchmarks.sweeps.run SWEEP.yaml [--out DIR] [--devices 0,1] [--only ARM:SEED] [--time-limit S]
        [--report-only]

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
is done; ``--only`` trains the named runs alone. Raising ``env_steps`` continues every run from its
checkpoint and evaluates it again (an evaluation of an earlier checkpoint is never reported). The report
(``benchmarks.sweeps.report``): ``sweep.json``, ``sweep.md`` and one plot per arm plus ``sweep.png`` in
``OUT``; every figure with its 95 % interval, the arms against the first.

The sweep file is checked before anything runs (``benchmarks.sweeps.spec``).
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

import jax

from benchmarks.sweeps import checkpoints
from benchmarks.sweeps import report as sweep_report
from benchmarks.sweeps.spec import Sweep, load

GRID_TAG = "grid"  # robustness_grid.json in each run's sweep_grid/
GRACE_S = 90  # --time-limit: SIGTERM this long before the limit (the epoch in flight ends, a checkpoint is written)


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


def select(jobs: list[Job], only: str | None) -> list[Job]:
    """The jobs named by ``--only`` (``ARM:SEED`` items, comma-separated) in the order named, which is the
    order the GPUs take them; all, in plan order, without it. A sweep split over calls or hosts trains a part
    at a time, and its report covers every run present."""
    if not only:
        return jobs
    known = {f"{j.arm}:{j.seed}": j for j in jobs}
    wanted = [item.strip() for item in only.split(",") if item.strip()]
    unknown = [w for w in wanted if w not in known]
    if unknown:
        raise ValueError(f"--only: no run {', '.join(unknown)} in this sweep; valid: {', '.join(known)}")
    return [known[name] for name in dict.fromkeys(wanted)]


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
        if job.every_checkpoint and job.evaluate:
            pending = checkpoints.pending(job.run_dir)
            for args in checkpoints.commands(job.evaluate, pending, job.run_dir):
                names = [Path(a).name for a in args[args.index("--checkpoint") + 1 :]]
                print(f"[{device}] evaluate {job.arm} seed {job.seed} {', '.join(names)}", flush=True)
                if self._call(args, device, log) == 0:
                    for path in pending:
                        if path.name in names:
                            checkpoints.write_clock(path, job.run_dir)
            if not sweep_report.is_current(job.run_dir / "sweep_eval", job.run_dir):
                checkpoints.as_final(job.run_dir, job.run_dir / "sweep_eval")
        if job.evaluate and not sweep_report.is_current(job.run_dir / "sweep_eval", job.run_dir):
            print(f"[{device}] evaluate {job.arm} seed {job.seed}", flush=True)
            if self._call(job.evaluate, device, log) != 0:
                shutil.rmtree(job.run_dir / "sweep_eval", ignore_errors=True)
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
    parser.add_argument("--only", default=None, help="train only these runs now, ARM:SEED[,ARM:SEED...]")
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
        out = Path(args.out or Path("runs") / "sweeps" / sweep.name)
        jobs, refs = plan(sweep, out), references(sweep, out)
        now = select(jobs, args.only) + ([] if args.only else refs)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    devices = [d.strip() for d in args.devices.split(",")] if args.devices else None
    if not args.report_only:
        devices = devices or local_gpus()
        deadline = None if args.time_limit is None else start + args.time_limit
        print(f"sweep {sweep.name}: {len(now)} runs of {sweep.env_steps:,} env steps on devices {devices}", flush=True)
        Runner(devices, deadline).run(now, sweep.env_steps)
    sweep_report.write(sweep, jobs, out, gpu_names(), rewrite=args.report_only, references=refs, devices=devices)
    print((out / "sweep.md").read_text(), end="")  # the report as written: arms, runs, checkpoints, grid
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The training run: set-up, resume, the host loop over jitted epochs, logging and checkpoints.

``train(config, run_dir)`` builds the learner and its collection strategy (``train.devices.strategies``),
starts from scratch, a checkpoint (``--resume``) or another run's networks (``run.init_from``), and
runs epochs until ``run.num_timesteps``, logging and checkpointing between them (the run state a
checkpoint holds: ``train.run.saved``). Several processes (``train.devices.distributed``):
every process runs the same loop on its local devices; only process 0 writes the run dir.
"""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from hsa_mjx.batch.auto_reset import summarize
from hsa_mjx.config import to_dict as env_to_dict
from hsa_mjx.curricula import goal_curriculum
from hsa_mjx.sim import backend
from hsa_mjx.task import warp_builder

from .config import TrainConfig, to_dict, validate_devices
from .devices import distributed, strategies
from .devices.base import envs_per_device, envs_per_process
from .run import checkpoint, plots, saved
from .run.folder import portable, prepare_run_dir
from .run.logger import HEADLINE, MetricsLogger, ProgressBar, process_age_s
from .run.startup import Startup
from .run.warm_start import describe, read_init_from, warm_start


class StopFlag:
    """Turns Ctrl-C / SIGTERM into a flag checked between epochs, so state is never half-donated.

    A second signal stops hard, unless it comes within ``repeat_s`` of the first: a signal sent to
    both a forwarding wrapper (``timeout``, ``srun``) and the process reaches it twice at once.
    """

    def __init__(self, repeat_s: float = 1.0):
        self.raised, self._old, self._first, self.repeat_s = False, {}, 0.0, repeat_s

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[sig] = signal.signal(sig, self.handle)
            except ValueError:  # not the main thread: no handler, stop only by finishing
                pass
        return self

    def handle(self, signum: int, frame: Any) -> None:
        """The signal handler: raise the flag, or stop hard on a second, later signal."""
        if self.raised:
            if time.monotonic() - self._first < self.repeat_s:  # the same request, forwarded twice
                return
            raise KeyboardInterrupt  # second Ctrl-C: stop hard
        self.raised, self._first = True, time.monotonic()
        print(f"\nsignal {signum}: finishing this epoch, writing a checkpoint, then stopping", flush=True)

    def __exit__(self, *exc):
        for sig, handler in self._old.items():
            signal.signal(sig, handler)


class _NoLogger:
    """Stands in for the metrics logger on processes other than 0 (they write nothing)."""

    def log(self, step: int, metrics: dict) -> None:
        """Drop the record."""

    def close(self) -> None:
        """Nothing to close."""


def select_devices(config: TrainConfig) -> list:
    """This process's devices to use, the run's split over every process's devices checked (ValueError)."""
    devices = jax.local_devices()
    if config.run.num_devices:
        if config.run.num_devices > len(devices):
            raise ValueError(f"run.num_devices = {config.run.num_devices} but only {len(devices)} local devices exist")
        devices = devices[: config.run.num_devices]
    validate_devices(config, distributed.global_device_count(devices))
    return devices


@dataclasses.dataclass
class Run:
    """One run's fixed parts: its config, run dir, strategy and what every summary and checkpoint records."""

    config: TrainConfig
    run_dir: Path
    strategy: strategies.Strategy
    quiet: bool
    extra: dict  # metadata of every checkpoint and the summary (the physics backend)
    startup: Startup  # this call's start-up parts, in the summary
    walltime_before: float = 0.0  # the training clock of the calls before this one (a resumed run's)


def train(
    config: TrainConfig, run_dir: str | Path, resume: bool = False, quiet: bool = False, overwrite: bool = False
) -> dict:
    """Train the learner ``run.learner`` names (PPO or TD3) with the curricula; checkpoints, logs and plots go
    to ``run_dir``. Returns a summary.

    ``resume`` continues the run in ``run_dir`` from its newest readable checkpoint; ``overwrite``
    replaces a run already there (otherwise a run dir holding one is refused).
    """
    run_dir, startup = Path(run_dir), Startup()
    devices = select_devices(config)
    distributed.check_agreement(to_dict(config), devices)  # every process: one config, as many devices
    init = None if resume else read_init_from(config)
    meta = prepare_run_dir(run_dir, to_dict(config), resume, overwrite)
    if resume and meta is None:  # the same SLURM job, requeued before its first checkpoint: a fresh start
        init = read_init_from(config)
    if distributed.is_main() and not quiet:
        print(_announce(config, run_dir, devices), flush=True)
    builder = start_warp_builder(config, devices)  # first: it builds beside the env, state and compile
    strategy = strategies.build(config, devices)
    startup.mark("build_s")
    extra = {
        "physics_backend": strategy.learner.env.physics_backend,
        "collection": strategy.name,  # run.collection with auto resolved
        "devices": len(devices) * jax.process_count(),
        "processes": jax.process_count(),
        "calls": int(meta.get("calls", 1)) + 1 if meta is not None else 1,  # this one and those it resumed
    }
    before = float(meta.get("training_walltime_s", 0.0)) if meta is not None else 0.0
    run = Run(config, run_dir, strategy, quiet, extra, startup, before)
    ts, goal, key, step, levels = _start(run, meta, init)
    startup.mark("init_s")
    key, k_env = jax.random.split(key)
    state = strategy.reset(distributed.env_keys(k_env, config.run.num_envs, devices), goal, levels)
    jax.block_until_ready(state)
    startup.mark("reset_s")
    if distributed.is_main() and not quiet:
        print(f"compiling the training epoch on the {run.extra['physics_backend']} backend...", flush=True)
    ts, started = strategy.place(ts), time.perf_counter()
    compile_ahead(run, ts, state, builder)
    return run_epochs(run, ts, state, key, step, resumed=meta is not None, started=started)


def start_warp_builder(config: TrainConfig, devices: list) -> warp_builder.Builder | None:
    """On MJX's Warp backend on a GPU, the helper process that builds MuJoCo Warp's kernels for this run's
    env (``hsa_mjx.task.warp_builder``); None elsewhere."""
    if devices[0].platform != "gpu":
        return None
    physics = backend.resolve(config.env.physics.backend, devices[0])
    return warp_builder.start(env_to_dict(config.env), envs_per_device(config, devices), physics, devices[0])


def compile_ahead(run: Run, ts: Any, state: Any, builder: warp_builder.Builder | None = None) -> None:
    """The training epoch compiled before the first one runs where the strategy can (one device); meanwhile
    the Warp kernel helper is waited for or, without one, the env's physics warmed up on a thread (MuJoCo
    Warp's kernels for this model). The start-up parts ``epoch_compile_s`` and ``warp_warm_up_s`` or the
    helper's report. Elsewhere the first epoch compiles it, after the helper is done."""
    strategy, seconds = run.strategy, {}

    def physics_ready() -> None:
        if builder is not None:
            run.startup.warp_builder = builder.wait()
        else:
            seconds["warp_warm_up_s"] = strategy.learner.env.warm_up_physics()

    keys = distributed.epoch_keys(jax.random.PRNGKey(0), strategy.devices)  # shaped as every epoch's keys
    jax.block_until_ready((ts, state))  # nothing runs on the device while the warm-up does
    if strategy.compile_ahead(ts, state, keys, during=physics_ready):
        run.startup.mark("epoch_compile_s")
        if seconds.get("warp_warm_up_s") is not None:
            run.startup.parts["warp_warm_up_s"] = seconds["warp_warm_up_s"]
    elif builder is not None:
        physics_ready()


def _start(run: Run, meta: dict | None, init: dict | None) -> tuple:
    """(learner state, goal curriculum, PRNG key, step, every env's levels) to start from: fresh, resumed
    from ``meta``'s checkpoint, or warm-started from ``init``."""
    config, learner = run.config, run.strategy.learner
    key, k_init = jax.random.split(jax.random.PRNGKey(config.run.seed))
    ts = learner.init_state(k_init)
    goal = goal_curriculum.init(config.goal_curriculum, tuple(config.env.goal.radial_range))
    if meta is not None:
        ts, goal, key = saved.restore(meta["path"], ts, goal, key)
        levels = saved.restore_levels(config, meta, envs_per_process(config))
        print(f"resumed from {meta['path']} at step {int(meta['step']):,}", flush=True)
        return ts, goal, key, int(meta["step"]), levels
    if init is not None:
        ts = warm_start(config, ts, init)
        print(describe(init), flush=True)
    return ts, goal, key, 0, None


def _announce(config: TrainConfig, run_dir: Path, devices: list) -> str:
    """The lines printed before anything compiles: where the run goes and what it trains."""
    env, run = config.env, config.run
    return (
        f"run dir: {run_dir}\n"
        f"  env {env.name} ({env.scene} scene, goals {env.goal.mode}, physics.backend {env.physics.backend}), "
        f"{run.num_envs:,} envs on {len(devices)} {devices[0].platform.upper()} device(s), "
        f"{run.num_timesteps:,} env steps, seed {run.seed}"
    )


def final_step(step: int, num_timesteps: int, steps_per_epoch: int) -> int:
    """The step a run from ``step`` ends at: whole epochs until ``num_timesteps`` is reached (or passed)."""
    return step + max(0, -(-(num_timesteps - step) // steps_per_epoch)) * steps_per_epoch


def run_epochs(
    run: Run, ts: Any, state: Any, key: jax.Array, step: int, resumed: bool = False, started: float | None = None
) -> dict:
    """Run epochs until ``num_timesteps``; log every ``epochs_per_log``; checkpoint on the interval. The
    training clock counts from ``started`` (``time.perf_counter``; default now): from before the epoch's
    compile ahead, so it holds that compile as it holds a first epoch's that compiles."""
    config, strategy, main = run.config, run.strategy, distributed.is_main()
    logger = MetricsLogger(run.run_dir, resume_step=step if resumed else None) if main else _NoLogger()
    steps_per_epoch = strategy.learner.env_steps_per_epoch
    bar = ProgressBar(final_step(step, config.run.num_timesteps, steps_per_epoch), start=step)
    t_start = time.perf_counter() if started is None else started
    last_ckpt, epoch, latest = step, 0, {}  # latest: each headline key's last value
    next_ckpt_s = next_checkpoint_s(run.walltime_before, config.run)  # on the run's clock, across calls
    first_epoch_s, stopped, totals, budget_spent = None, False, {}, False
    with StopFlag() as stop:
        while step < config.run.num_timesteps and not (stopped := distributed.any_process(stop.raised)):
            if budget_spent := out_of_time(run, time.perf_counter() - t_start):
                break
            key, k_epoch = jax.random.split(key)
            t0 = time.perf_counter()
            ts, state, out = strategy.epoch(ts, state, distributed.epoch_keys(k_epoch, strategy.devices))
            out = jax.device_get(out)
            dt = time.perf_counter() - t0
            first_epoch_s = dt if first_epoch_s is None else first_epoch_s
            run.startup.epoch(dt)
            step, epoch = step + steps_per_epoch, epoch + 1
            for k, v in out["totals"].items():
                totals[k] = totals.get(k, 0.0) + float(np.asarray(v)[0])
            if epoch % config.run.epochs_per_log == 0 or step >= config.run.num_timesteps:
                record = _record(run, out, totals, strategy.goal_curriculum(state), steps_per_epoch / dt, t_start)
                logger.log(step, record)
                latest.update({k: record[k] for k in HEADLINE if k in record})  # a log without episodes has none
                totals = {}
                if main and not run.quiet:
                    bar.update(step, {k: record[k] for k in HEADLINE if k in record})
            elapsed = time.perf_counter() - t_start
            due = checkpoint_due(step - last_ckpt, run.walltime_before + elapsed, next_ckpt_s, config.run)
            if config.run.checkpoint_every_s > 0:  # processes' clocks differ: due on any, due on all (it gathers)
                due = distributed.any_process(due)
            if due:
                _save(run, step, ts, state, key, elapsed)
                last_ckpt, next_ckpt_s = step, next_checkpoint_s(run.walltime_before + elapsed, config.run)
        if step != last_ckpt or not checkpoint.list_checkpoints(run.run_dir):
            _save(run, step, ts, state, key, time.perf_counter() - t_start)
    bar.close()
    logger.close()
    summary = {"env_steps": step, "wall_s": time.perf_counter() - t_start, "first_epoch_s": first_epoch_s}
    summary.update(interrupted=stopped, checkpoint=None, **run.extra, **{k: latest.get(k) for k in HEADLINE})
    summary["stopped_by"] = "max_training_s" if budget_spent else "signal" if stopped else "num_timesteps"
    summary["startup"] = run.startup.record()
    return _finish(run.run_dir, summary, config.run.learner) if main else summary


def out_of_time(run: Run, seconds: float) -> bool:
    """Whether the run's training clock (this call's ``seconds`` after those before it) has reached
    ``run.max_training_s`` (never when 0), on any process."""
    limit = run.config.run.max_training_s
    return limit > 0 and distributed.any_process(run.walltime_before + seconds >= limit)


def next_checkpoint_s(clock: float, run: Any) -> float:
    """The training clock of the next timed checkpoint after ``clock``: the next multiple of
    ``run.checkpoint_every_s`` (``inf`` where unset). Why multiples of the run's clock: a run resumed over
    several calls keeps one schedule (600, 1200, 1800 s), whatever time each call started at."""
    every = run.checkpoint_every_s
    return (math.floor(clock / every) + 1) * every if every > 0 else math.inf


def checkpoint_due(steps: int, clock: float, due_s: float, run: Any) -> bool:
    """Whether a checkpoint is due ``steps`` env steps after the last, at training clock ``clock``: every
    ``run.checkpoint_every`` env steps, and once the clock reaches ``due_s`` (:func:`next_checkpoint_s`)."""
    return steps >= run.checkpoint_every or clock >= due_s


def _finish(run_dir: Path, summary: dict, learner: str) -> dict:
    """Process 0: learning curves, the learner's diagnostics and ``summary.json`` (with the latest checkpoint)."""
    plots.learning_curves(run_dir / "metrics.jsonl", run_dir / "learning_curve.png")
    plots.learner_diagnostics(run_dir / "metrics.jsonl", run_dir, learner)
    summary = {**summary, "checkpoint": portable(checkpoint.latest(run_dir), run_dir)}  # within the run dir
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def _record(run: Run, out: dict, totals: dict, goal: Any, sps: float, t_start: float) -> dict:
    """One log record: episode statistics, losses, curricula and throughput."""
    record = summarize(totals, run.config.env.terrain.levels)
    losses = distributed.all_devices(out["losses"])  # every process's devices, not only this one's
    record.update({f"loss/{k}": float(np.mean(v)) for k, v in losses.items()})
    metrics = run.strategy.learner.rules.goal_metrics(jax.device_get(goal))
    record.update({k: float(v) for k, v in metrics.items()})
    record["training/env_steps_per_s"] = sps
    record["training/walltime"] = time.perf_counter() - t_start
    record["training/since_launch"] = process_age_s()  # the walltime and what came before it: imports, env build
    return record


def _save(run: Run, step: int, ts: Any, state: Any, key: jax.Array, walltime: float) -> None:
    """Checkpoint the learner (first device's copy), the curricula (every process's envs' terrain and
    randomisation levels, gathered) and rng, with the training clock (``walltime`` s of this call after
    those before it); process 0 writes."""
    config, strategy = run.config, run.strategy
    extra = {**run.extra, "training_walltime_s": round(run.walltime_before + walltime, 3)}
    terrain = randomization = None
    if config.terrain_curriculum.enabled or config.randomization_curriculum.enabled:  # every process gathers
        mine = strategy.env_levels(state)
        levels = {k: np.asarray(distributed.all_processes(v)).reshape(-1) for k, v in mine.items()}
        randomization = levels.pop("randomization") if config.randomization_curriculum.enabled else None
        terrain = levels if config.terrain_curriculum.enabled else None
    if not distributed.is_main():
        return
    if terrain is not None:
        extra = {**extra, "terrain_envs": int(terrain["level"].shape[0])}
    if randomization is not None:
        extra = {**extra, "randomization_envs": int(randomization.shape[0])}
    payload = saved.payload(strategy.first(ts), strategy.goal_curriculum(state), key, terrain, randomization)
    checkpoint.save(run.run_dir, step, payload, to_dict(config), keep=config.run.keep_checkpoints, extra=extra)

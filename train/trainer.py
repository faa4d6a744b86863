"""The training run: set-up, resume, the host loop over jitted epochs, logging and checkpoints.

Several processes (``train.distributed``): every process runs the same loop on its local devices;
only process 0 writes the run dir.
"""

from __future__ import annotations

import json
import shutil
import signal
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import yaml

from hsa_mjx.batch.auto_reset import summarize
from hsa_mjx.curricula import goal as cur
from hsa_mjx.curricula import terrain as tcur
from train import checkpoint, distributed, plots
from train import config as tcfg
from train.logger import HEADLINE, MetricsLogger, ProgressBar
from train.per_device import make_learner
from train.ppo import AXIS, TrainingState, init_training_state, replicate, unreplicate
from train.warm_start import read_init_from, warm_start


class _StopFlag:
    """Turns Ctrl-C / SIGTERM into a flag checked between epochs, so state is never half-donated.

    A second signal stops hard, unless it comes within ``repeat_s`` of the first: a signal sent to
    both a forwarding wrapper (``timeout``, ``srun``) and the process reaches it twice at once.
    """

    def __init__(self, repeat_s: float = 1.0):
        self.raised, self._old, self._first, self.repeat_s = False, {}, 0.0, repeat_s

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[sig] = signal.signal(sig, self._handle)
            except ValueError:  # not the main thread: no handler, stop only by finishing
                pass
        return self

    def _handle(self, signum, frame):
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


def select_devices(config: tcfg.TrainConfig) -> list:
    """This process's devices to use (num_envs and the minibatch size validated against all processes' devices)."""
    devices = jax.local_devices()
    if config.run.num_devices:
        if config.run.num_devices > len(devices):
            raise ValueError(f"run.num_devices = {config.run.num_devices} but only {len(devices)} local devices exist")
        devices = devices[: config.run.num_devices]
    tcfg.validate(config, device_count=distributed.global_device_count(devices))
    return devices


def replicate_for_pmap(tree: Any, devices: list) -> Any:
    """Copies of ``tree`` on ``devices``, laid out as the pmapped epoch returns its outputs.

    ``replicate`` places the copies on a mesh axis of its own name; the epoch's outputs live on the
    ``devices`` axis, so feeding the former to the first epoch and the latter to the second made
    ``pmap`` compile the epoch twice. A pmapped identity puts the copies on the epoch's axis.
    """
    return jax.pmap(lambda x: x, axis_name=AXIS)(replicate(tree, devices))


def _payload(
    ts: TrainingState, cstate: cur.CurriculumState, key: jax.Array, terrain: dict | None = None
) -> dict[str, Any]:
    """What a checkpoint holds; ``terrain``: every env's terrain levels (with the terrain curriculum)."""
    payload = {"training_state": ts, "curriculum": cstate, "rng": key}
    return payload if terrain is None else {**payload, "terrain_levels": terrain}


def restore_terrain(config: tcfg.TrainConfig, meta: dict, batch: int) -> tcur.TerrainLevels | None:
    """The checkpoint's per-env terrain levels for this process's ``batch`` envs (None: start them afresh)."""
    saved = meta.get("terrain_envs")
    if not config.terrain_curriculum.enabled or not saved:
        return None
    template = {"terrain_levels": {k: np.zeros((saved,), np.int32) for k in ("row", "level")}}
    restored = checkpoint.load(meta["path"], template)["terrain_levels"]
    if (
        int(np.max(restored["row"], initial=0)) >= len(config.env.terrain.types)
        or int(np.max(restored["level"], initial=0)) >= config.env.terrain.levels
    ):
        raise ValueError(f"checkpoint {meta['path']}: its terrain levels do not fit env.terrain (types, levels)")
    if saved == batch * jax.process_count():  # every process's envs, in process order: this one's share
        start = jax.process_index() * batch
        restored = {k: v[start : start + batch] for k, v in restored.items()}
    return tcur.from_host(restored, batch, config.run.seed)


RUN_FILES = ("checkpoints", "metrics.jsonl", "tensorboard", "config.yaml", "summary.json", "learning_curve.png")


def run_files(run_dir: Path) -> list[str]:
    """What a run left in ``run_dir`` (its own file names only)."""
    return [name for name in RUN_FILES if (run_dir / name).exists()]


def _current_keys(saved: dict) -> dict:
    """A saved config with older keys mapped onto the current ones (as loading it does); as saved when
    it no longer loads (the comparison then names what differs)."""
    try:
        return json.loads(json.dumps(tcfg.to_dict(tcfg.from_dict(saved))))
    except (ValueError, TypeError):
        return saved


def prepare_run_dir(run_dir: Path, config_dict: dict, resume: bool, overwrite: bool = False) -> dict | None:
    """Create the run dir (process 0), refuse to write into another run's files, and read the checkpoint
    to resume (the newest readable one; before any compile). When one process refuses, all stop."""
    refused = meta = None
    try:
        meta = _resume_meta(run_dir, config_dict) if resume else _start_run_dir(run_dir, config_dict, overwrite)
    except (ValueError, FileNotFoundError) as err:
        refused = err
    if distributed.any_process(refused is not None):  # a process going on alone would wait for the others
        raise refused or ValueError("another process refused to start the run: its output says why")
    return meta


def _start_run_dir(run_dir: Path, config_dict: dict, overwrite: bool) -> None:
    """Process 0 alone looks at and writes the run dir (the others may see its files appear meanwhile)."""
    if not distributed.is_main():
        return None
    found = run_files(run_dir)
    if found and not overwrite:
        raise ValueError(
            f"{run_dir} already holds a run ({', '.join(found)}); pass --resume to continue it, "
            f"--overwrite to start it afresh, or choose another --run-dir"
        )
    for name in found:  # --overwrite: only the run's own files go
        target = run_dir / name
        shutil.rmtree(target) if target.is_dir() else target.unlink()
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config_dict, sort_keys=False))
    return None


def _resume_meta(run_dir: Path, config_dict: dict) -> dict:
    """The newest readable checkpoint's metadata (and ``path``), refused when its config differs."""
    path, skipped = checkpoint.latest_readable(run_dir)
    for reason in skipped:
        print(f"warning: skipping unreadable checkpoint {reason}", flush=True)
    if skipped:
        print(f"resuming from the newest readable checkpoint, {path.name}", flush=True)
    meta = checkpoint.read_meta(path)
    now = json.loads(json.dumps(config_dict))
    defaults = json.loads(json.dumps(tcfg.to_dict(tcfg.TrainConfig())))
    bad = checkpoint.incompatibilities(_current_keys(meta["config"]), now, defaults)
    if bad:
        raise ValueError(
            f"checkpoint {path} was written with a different config; these keys differ: {bad}. "
            f"Resume with the run's own config ({run_dir / 'config.yaml'}) or start a new run dir."
        )
    meta["path"] = path
    return meta


def train(
    config: tcfg.TrainConfig, run_dir: str | Path, resume: bool = False, quiet: bool = False, overwrite: bool = False
) -> dict:
    """Train PPO with the curriculum; checkpoints, logs and plots go to ``run_dir``. Returns a summary.

    ``resume`` continues the run in ``run_dir`` from its newest readable checkpoint; ``overwrite``
    replaces a run already there (otherwise a run dir holding one is refused).
    """
    run_dir = Path(run_dir)
    config_dict = tcfg.to_dict(config)
    devices = select_devices(config)
    init = None if resume else read_init_from(config)
    meta = prepare_run_dir(run_dir, config_dict, resume, overwrite)
    if distributed.is_main() and not quiet:
        print(_announce(config, run_dir, devices), flush=True)
    learner = make_learner(config, devices)
    env = learner.env
    key = jax.random.PRNGKey(config.run.seed)
    key, k_init = jax.random.split(key)
    ts = init_training_state(config, learner.networks, k_init, learner.network_input_size)
    cstate, step, levels = cur.init(config.curriculum), 0, None
    if meta is not None:
        restored = checkpoint.load(meta["path"], _payload(ts, cstate, key))
        ts, cstate = jax.tree.map(jnp.asarray, (restored["training_state"], restored["curriculum"]))
        key, step = jnp.asarray(restored["rng"], jnp.uint32), int(meta["step"])
        levels = restore_terrain(config, meta, config.run.num_envs // jax.process_count())
        print(f"resumed from {meta['path']} at step {step:,}", flush=True)
    elif init is not None:
        ts = warm_start(ts, init, key)
        what = (
            "the policy network and observation statistics of the policy file"
            if "policy" in init
            else "networks and observation statistics from"
        )
        print(
            f"starting from {what} {init['path']} (trained for {init['step']:,} env steps)"
            + (f", statistics' count restarted at {init['count']:,}" if init["count"] else "")
            + ("; the value network starts fresh" if "policy" in init else ""),
            flush=True,
        )
    key, k_env = jax.random.split(key)
    env_keys = distributed.env_keys(k_env, config.run.num_envs, devices)
    ts_r = replicate_for_pmap(ts, devices)
    state = learner.reset(env_keys, cstate, levels)
    extra = {"physics_backend": env.physics_backend}
    if distributed.is_main() and not quiet:
        print(
            f"compiling the training epoch on the {env.physics_backend} backend (the first epoch includes it)...",
            flush=True,
        )
    return _loop(config, learner, devices, run_dir, ts_r, state, key, step, quiet, extra, resumed=meta is not None)


def _announce(config: tcfg.TrainConfig, run_dir: Path, devices: list) -> str:
    """The lines printed before anything compiles: where the run goes and what it trains."""
    env, run = config.env, config.run
    return (
        f"run dir: {run_dir}\n"
        f"  env {env.name} ({env.scene} scene, goals {env.goal.mode}, physics.backend {env.physics.backend}), "
        f"{run.num_envs:,} envs on {len(devices)} {devices[0].platform.upper()} device(s), "
        f"{run.num_timesteps:,} env steps, seed {run.seed}"
    )


def _loop(config, learner, devices, run_dir, ts, state, key, step, quiet, extra, resumed: bool = False) -> dict:
    """Run epochs until ``num_timesteps``; log every ``epochs_per_log``; checkpoint on the interval."""
    main = distributed.is_main()
    logger = MetricsLogger(run_dir, resume_step=step if resumed else None) if main else _NoLogger()
    bar = ProgressBar(config.run.num_timesteps, start=step)
    t_start, last_ckpt, epoch, latest = time.perf_counter(), step, 0, {}  # latest: each headline key's last value
    first_epoch_s, stopped = None, False
    totals_acc: dict[str, float] = {}
    with _StopFlag() as stop:
        while step < config.run.num_timesteps and not (stopped := distributed.any_process(stop.raised)):
            key, k_epoch = jax.random.split(key)
            t0 = time.perf_counter()
            ts, state, out = learner.epoch(ts, state, distributed.epoch_keys(k_epoch, devices))
            out = jax.device_get(out)
            dt = time.perf_counter() - t0
            first_epoch_s = dt if first_epoch_s is None else first_epoch_s
            step, epoch = step + learner.env_steps_per_epoch, epoch + 1
            for k, v in out["totals"].items():
                totals_acc[k] = totals_acc.get(k, 0.0) + float(np.asarray(v)[0])
            if epoch % config.run.epochs_per_log == 0 or step >= config.run.num_timesteps:
                record = _record(
                    out, totals_acc, learner.goal_curriculum(state), config, learner.env_steps_per_epoch / dt, t_start
                )
                logger.log(step, record)
                latest.update({k: record[k] for k in HEADLINE if k in record})  # a log without episodes has none
                totals_acc = {}
                if main and not quiet:
                    bar.update(step, {k: record[k] for k in HEADLINE if k in record})
            if step - last_ckpt >= config.run.checkpoint_every:
                _save(run_dir, step, ts, state, key, config, learner, extra)
                last_ckpt = step
        if step != last_ckpt or not checkpoint.list_checkpoints(run_dir):
            _save(run_dir, step, ts, state, key, config, learner, extra)
    bar.close()
    logger.close()
    summary = {
        "env_steps": step,
        "wall_s": time.perf_counter() - t_start,
        "first_epoch_s": first_epoch_s,
        "interrupted": stopped,
        "checkpoint": None,
        **extra,
        **{k: latest.get(k) for k in HEADLINE},
    }
    return _finish(run_dir, summary) if main else summary


def _finish(run_dir: Path, summary: dict) -> dict:
    """Process 0: learning curves and ``summary.json`` (with the latest checkpoint) into the run dir."""
    plots.learning_curves(run_dir / "metrics.jsonl", run_dir / "learning_curve.png")
    summary = {**summary, "checkpoint": str(checkpoint.latest(run_dir))}
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def _record(out: dict, totals: dict, goal: cur.CurriculumState, config, sps: float, t_start: float) -> dict:
    """One log record: episode statistics, losses, curriculum and throughput."""
    record = summarize(totals, config.env.terrain.levels)
    losses = distributed.all_devices(out["losses"])  # every process's devices, not only this one's
    record.update({f"loss/{k}": float(np.mean(v)) for k, v in losses.items()})
    record.update({k: float(v) for k, v in cur.metrics(jax.device_get(goal), config.curriculum).items()})
    record["training/env_steps_per_s"] = sps
    record["training/walltime"] = time.perf_counter() - t_start
    return record


def _save(run_dir: Path, step: int, ts, state, key, config: tcfg.TrainConfig, learner, extra: dict) -> None:
    """Checkpoint the learner (first device's copy), both curricula (every process's envs' terrain levels,
    gathered) and rng; process 0 writes."""
    terrain = None
    if config.terrain_curriculum.enabled:  # every process takes part in the gather
        mine = learner.terrain_levels(state)
        terrain = {k: np.asarray(distributed.all_processes(v)).reshape(-1) for k, v in mine.items()}
    if not distributed.is_main():
        return
    if terrain is not None:
        extra = {**extra, "terrain_envs": int(terrain["row"].shape[0])}
    payload = _payload(unreplicate(ts), learner.goal_curriculum(state), key, terrain)
    checkpoint.save(run_dir, step, payload, tcfg.to_dict(config), keep=config.run.keep_checkpoints, extra=extra)

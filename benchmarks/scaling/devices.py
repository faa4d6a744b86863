"""Scaling over the devices of one host: env-steps/s of the env step and of PPO training, for 1, 2, 4, ... devices.

For every device count k (powers of two up to ``jax.local_device_count()``, plus that maximum) at a
fixed batch per device (weak scaling: k times the envs, the PPO minibatch and the epoch scaled with
them, so every device does the same work at every k), in one process:

The devices share the work as the trainer's collection strategy does (``run.collection``, default
``auto``: ``one_device`` on one device, ``thread_per_device`` on 2+ GPUs, ``pmap`` on several CPUs;
``train.devices.strategies``; ``--set run.collection=thread_per_device`` measures that path at k = 1
too). Each row names it (``collection``).

- **ppo** (first: the training figure): the learner's epoch (collection, observation statistics,
  curriculum, SGD with gradients averaged over the devices), one PPO iteration of the config per
  epoch by default.
- **env**: the full training env step (``AutoResetEnv``: physics, observation, reward,
  termination, auto-reset, curriculum), random actions, ``--steps`` steps per call under
  ``lax.scan``, on every device at once: jitted for one device, ``pmap``-ed (outcomes gathered over
  the devices every step) or jitted once per device (one host thread per device);
  the loop of ``benchmarks.speed.throughput``.
- **collect** (the split, best effort after the rest): the epoch's collections alone (policy plus
  env steps), so the update's share is the epoch time minus it.

Each is called once to compile and warm up (compile seconds: that call less the median call),
then timed (``block_until_ready``); rates use the median call. Speed-up and efficiency (speed-up /
device ratio) are relative to the smallest k measured. Results go to ``--out-dir`` as
``scaling_<tag>.{json,md,png}`` (tag default: the device name), rewritten after every measurement.

    python -m benchmarks.scaling.devices [--config FILE] [--envs-per-device N] [--devices 1,2,4] [--steps K]
        [--repeats R] [--epochs E] [--iterations-per-epoch I] [--no-split] [--budget-s S] [--tag TAG]
        [--out-dir benchmarks/results/scaling] [--compile-cache DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import jax
import numpy as np

import benchmarks.scaling.report
from benchmarks.run_info import row_provenance, run_info
from benchmarks.speed import loops as throughput_loops
from benchmarks.speed.report import slug
from hsa_mjx.batch.auto_reset import AutoResetEnv
from hsa_mjx.curricula import goal_curriculum
from train.config import TrainConfig, default_config, load, validate_devices
from train.devices import distributed, strategies
from train.learners.ppo.learner import AXIS
from train.learners.ppo.networks import init_training_state

GPU_DEFAULTS = {"envs_per_device": 8192, "steps": 16, "repeats": 3, "epochs": 2}
CPU_DEFAULTS = {"envs_per_device": 4, "steps": 2, "repeats": 1, "epochs": 1}  # a pipeline check, not a result


def device_counts(available: int) -> list[int]:
    """1, 2, 4, ... up to ``available``, plus ``available`` itself."""
    if available < 1:
        raise ValueError(f"need at least one device, got {available}")
    counts = [2**i for i in range(available.bit_length()) if 2**i <= available]
    return counts + ([available] if counts[-1] != available else [])


def scaled_config(base: TrainConfig, envs_per_device: int, devices: int, iterations: int) -> TrainConfig:
    """``base`` at ``envs_per_device x devices`` envs with its minibatch and epoch scaled to match."""
    if envs_per_device < 1 or devices < 1 or iterations < 1:
        raise ValueError(
            f"envs per device, devices and iterations must be >= 1, got {envs_per_device}, {devices}, {iterations}"
        )
    num_envs = envs_per_device * devices
    batch = Fraction(base.ppo.batch_size * num_envs, base.run.num_envs)
    if batch.denominator != 1:
        raise ValueError(
            f"ppo.batch_size {base.ppo.batch_size} x {num_envs} envs / run.num_envs "
            f"{base.run.num_envs} is not a whole number; choose --envs-per-device so it is"
        )
    ppo = dataclasses.replace(base.ppo, batch_size=int(batch))
    steps = iterations * ppo.batch_size * ppo.num_minibatches * ppo.unroll_length
    run = dataclasses.replace(base.run, num_envs=num_envs, num_devices=devices, steps_per_epoch=steps)
    return validate_devices(dataclasses.replace(base, ppo=ppo, run=run), devices)


@dataclasses.dataclass
class Timed:
    """Compile time and the wall time of each timed call."""

    compile_s: float
    seconds: list[float]

    @property
    def median_s(self) -> float:
        """The median timed call."""
        return statistics.median(self.seconds)


def time_calls(call: Callable[[tuple], tuple], carry: tuple, calls: int) -> Timed:
    """Time ``carry = call(carry)``: a first (compiling) call, then ``calls`` timed ones.

    ``compile_s`` is the first call's time less the median timed call (compile and warm-up).
    """
    tic = time.perf_counter()
    carry = jax.block_until_ready(call(carry))
    first_s = time.perf_counter() - tic
    seconds = []
    for _ in range(calls):
        tic = time.perf_counter()
        carry = jax.block_until_ready(call(carry))
        seconds.append(time.perf_counter() - tic)
    return Timed(max(first_s - statistics.median(seconds), 0.0), seconds)


class Bench:
    """The pieces measured at one device count, built from the scaled config with the trainer's strategy."""

    def __init__(self, config: TrainConfig, devices: list, seed: int = 0):
        self.config, self.devices = config, devices
        self.strategy = strategies.build(config, devices)
        self.learner, self.env = self.strategy.learner, self.strategy.learner.env
        self.key = jax.random.PRNGKey(seed)
        self.donate = jax.default_backend() != "cpu"  # the CPU client cannot reuse donated buffers (JAX warns)

    @property
    def collection(self) -> str:
        """How the devices share the work (``run.collection``, ``auto`` resolved)."""
        return self.strategy.name

    def keys(self) -> jax.Array:
        """A fresh key per device."""
        self.key, key = jax.random.split(self.key)
        return distributed.epoch_keys(key, self.devices)

    def reset(self) -> Any:
        """Fresh envs on every device with the initial goal curriculum."""
        env_keys = distributed.env_keys(self.keys()[0], self.config.run.num_envs, self.devices)
        start = tuple(self.config.env.goal.radial_range)
        return self.strategy.reset(env_keys, goal_curriculum.init(self.config.goal_curriculum, start))

    def training_state(self) -> Any:
        """Fresh learner state, placed as the strategy's epoch takes it."""
        ts = init_training_state(self.config, self.learner.networks, self.keys()[0], self.learner.network_input_size)
        return self.strategy.place(ts)

    def env_loop(self, steps: int, repeats: int) -> Timed:
        """(i) ``steps`` random-action steps of the training batch env per call on every device."""
        if self.strategy.name == "thread_per_device":
            return self._env_loop_per_device(steps, repeats)
        _, run = throughput_loops.env_loop(self.env, AutoResetEnv(self.env), steps)
        donate = (0,) if self.donate else ()
        if self.strategy.name == "one_device":
            jitted = jax.jit(run, donate_argnums=donate)
            return time_calls(lambda carry: (jitted(carry[0], self.keys()[0])[0],), (self.reset().envs,), repeats)
        pmapped = jax.pmap(run, axis_name=AXIS, donate_argnums=donate)
        return time_calls(lambda carry: (pmapped(carry[0], self.keys())[0],), (self.reset().envs,), repeats)

    def _env_loop_per_device(self, steps: int, repeats: int) -> Timed:
        """The env loop jitted once per device (each with its own env), one thread each."""
        strategy, runs = self.strategy, []
        for batch_env in strategy.batch_envs:
            loop = throughput_loops.env_loop(batch_env.env, AutoResetEnv(batch_env.env), steps)[1]
            runs.append(jax.jit(loop, donate_argnums=(0,) if self.donate else ()))

        def call(carry: tuple) -> tuple:
            keys = [jax.device_put(np.asarray(k), d) for k, d in zip(np.asarray(self.keys()), self.devices)]
            return tuple(strategy.on_each(lambda i, s, k: runs[i](s, k)[0], carry, keys))

        return time_calls(call, tuple(piece.envs for piece in self.reset().pieces), repeats)

    def ppo_epochs(self, epochs: int) -> Timed:
        """(ii) PPO epochs with updates, as the trainer runs them."""
        return time_calls(
            lambda c: self.strategy.epoch(c[0], c[1], self.keys())[:2], (self.training_state(), self.reset()), epochs
        )

    def collection_epochs(self, epochs: int) -> Timed:
        """The epoch's collections alone (no learning)."""
        return time_calls(
            lambda c: self.strategy.collect_epoch(c[0], c[1], self.keys()),
            (self.training_state(), self.reset()),
            epochs,
        )


def _env_fields(timed: Timed, batch: int, steps: int) -> dict[str, Any]:
    """Row fields of the env loop: rate of the median call, compile time, every call."""
    return {
        "env_steps_per_s": round(batch * steps / timed.median_s, 1),
        "env_compile_s": round(timed.compile_s, 2),
        "env_call_s": [round(s, 4) for s in timed.seconds],
        "steps_per_call": steps,
    }


def _ppo_fields(timed: Timed, steps_per_epoch: int) -> dict[str, Any]:
    """Row fields of the PPO epochs: rate of the median epoch, compile time, every epoch."""
    return {
        "ppo_env_steps_per_s": round(steps_per_epoch / timed.median_s, 1),
        "ppo_compile_s": round(timed.compile_s, 2),
        "ppo_epoch_s": [round(s, 4) for s in timed.seconds],
        "env_steps_per_epoch": steps_per_epoch,
    }


def _split_fields(timed: Timed, row: dict[str, Any]) -> dict[str, Any]:
    """Collection rate and the update's share of an epoch (epoch median minus collection median)."""
    epoch_s = statistics.median(row["ppo_epoch_s"])
    update_s = max(epoch_s - timed.median_s, 0.0)
    return {
        "collect_env_steps_per_s": round(row["env_steps_per_epoch"] / timed.median_s, 1),
        "collect_compile_s": round(timed.compile_s, 2),
        "collect_s": [round(s, 4) for s in timed.seconds],
        "update_s": round(update_s, 4),
        "update_fraction": round(update_s / epoch_s, 4),
    }


def measure_count(
    args: argparse.Namespace, base: TrainConfig, k: int, over_budget: Callable[[], bool], info: dict[str, Any]
) -> tuple[dict[str, Any], Bench]:
    """Env loop and PPO epochs at ``k`` devices (each skipped once past the budget); the row and its bench."""
    config = scaled_config(base, args.envs_per_device, k, args.iterations_per_epoch)
    bench = Bench(config, jax.local_devices()[:k], args.seed)
    row = {
        "devices": k,
        "collection": bench.collection,
        "physics_backend": bench.env.physics_backend,
        "envs_per_device": args.envs_per_device,
        "num_envs": config.run.num_envs,
        "batch_size": config.ppo.batch_size,
        "iterations_per_epoch": args.iterations_per_epoch,
        **row_provenance(info),
    }
    # PPO first: traced before anything else in the process, its epoch lowers to the trainer's program
    # text, so a persistent compilation cache filled by a training run serves it
    if not over_budget():
        print(f"{k} device(s): PPO epochs ...", flush=True)
        row.update(_ppo_fields(bench.ppo_epochs(args.epochs), bench.learner.env_steps_per_epoch))
        print(f"  ppo {row['ppo_env_steps_per_s']:,.0f} env-steps/s (compile {row['ppo_compile_s']:.1f} s)", flush=True)
    if not over_budget():
        print(f"{k} device(s): env step, {config.run.num_envs:,} envs ...", flush=True)
        row.update(_env_fields(bench.env_loop(args.steps, args.repeats), config.run.num_envs, args.steps))
        print(f"  env {row['env_steps_per_s']:,.0f} env-steps/s (compile {row['env_compile_s']:.1f} s)", flush=True)
    return row, bench


def measure_split(args: argparse.Namespace, row: dict[str, Any], bench: Bench) -> dict[str, Any]:
    """The row with the collection/update split added."""
    print(f"{row['devices']} device(s): collection alone ...", flush=True)
    row = {**row, **_split_fields(bench.collection_epochs(args.epochs), row)}
    print(
        f"  collect {row['collect_env_steps_per_s']:,.0f} env-steps/s, update {100 * row['update_fraction']:.0f} % "
        f"of an epoch",
        flush=True,
    )
    return row


def run_all(args: argparse.Namespace, info: dict[str, Any], write: Callable[[list], None]) -> list[dict[str, Any]]:
    """Env and PPO at every device count, then the split while the budget lasts; write after each."""
    base = load(args.config, args.overrides)
    start = time.perf_counter()

    def over_budget():
        return time.perf_counter() - start > args.budget_s

    rows, benches = [], []
    for k in args.devices:
        row, bench = measure_count(args, base, k, over_budget, info)
        rows, benches = rows + [row], benches + [bench]
        write(benchmarks.scaling.report.with_speedups(rows))
    for i, (row, bench) in enumerate(zip(rows, benches)):
        if args.split and "ppo_epoch_s" in row and not over_budget():
            rows[i] = measure_split(args, row, bench)
            write(benchmarks.scaling.report.with_speedups(rows))
    skipped = [r["devices"] for r in rows if "ppo_env_steps_per_s" not in r or "env_steps_per_s" not in r]
    if skipped:
        print(f"past --budget-s {args.budget_s}: measurements missing at {skipped} device(s)", flush=True)
    return benchmarks.scaling.report.with_speedups(rows)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options; defaults depend on the backend (GPU: the full size, CPU: a pipeline check)."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default=None, help="training YAML (default: as python -m train picks)")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a config value before scaling (repeatable)",
    )
    p.add_argument(
        "--envs-per-device",
        type=int,
        default=None,
        help=f"GPU {GPU_DEFAULTS['envs_per_device']}, CPU {CPU_DEFAULTS['envs_per_device']}",
    )
    p.add_argument("--devices", default=None, help="comma list of device counts (default 1, 2, 4, ... and the max)")
    p.add_argument("--steps", type=int, default=None, help="env steps per timed env call")
    p.add_argument("--repeats", type=int, default=None, help="timed env calls")
    p.add_argument("--epochs", type=int, default=None, help="timed PPO (and collection) epochs after the warm-up one")
    p.add_argument("--iterations-per-epoch", type=int, default=1, help="PPO iterations per timed epoch")
    p.add_argument("--no-split", dest="split", action="store_false", help="skip the collection-only timing")
    p.add_argument("--budget-s", type=float, default=300.0, help="start no new measurement after this many s")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--tag", default="", help="output names scaling_<tag>.* (default: the device name)")
    p.add_argument("--out-dir", type=Path, default=Path("benchmarks/results/scaling"))
    p.add_argument("--compile-cache", type=Path, default=None, help="JAX persistent compilation cache dir")
    return p.parse_args(argv)


def resolve_defaults(args: argparse.Namespace) -> argparse.Namespace:
    """Fill backend-dependent defaults and check the device counts (ValueError naming the problem)."""
    defaults = GPU_DEFAULTS if jax.default_backend() == "gpu" else CPU_DEFAULTS
    for name, value in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    args.config = args.config or default_config()
    available = jax.local_device_count()
    if args.devices is None:
        args.devices = device_counts(available)
    else:
        try:
            args.devices = sorted({int(v) for v in args.devices.split(",") if v.strip()})
        except ValueError as err:
            raise ValueError(f"--devices must be a comma list of integers, got {args.devices!r}") from err
    if not args.devices or args.devices[0] < 1 or args.devices[-1] > available:
        raise ValueError(f"--devices {args.devices}: each must be between 1 and the {available} local devices")
    for name in ("steps", "repeats", "epochs"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} must be >= 1, got {getattr(args, name)}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.scaling.devices``; 2 on a bad option or config."""
    args = parse_args(argv)
    if args.compile_cache:
        jax.config.update("jax_compilation_cache_dir", str(args.compile_cache))
    try:
        args = resolve_defaults(args)
        for k in args.devices:  # every device count's config checked before anything compiles
            scaled_config(load(args.config, args.overrides), args.envs_per_device, k, args.iterations_per_epoch)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    info = run_info()
    stem = "scaling_" + slug(args.tag or info["device"])
    meta = {
        **info,
        "config": str(args.config),
        "overrides": args.overrides,
        "devices_measured": args.devices,
        "envs_per_device": args.envs_per_device,
        "steps_per_call": args.steps,
        "repeats": args.repeats,
        "epochs": args.epochs,
        "iterations_per_epoch": args.iterations_per_epoch,
    }
    print(
        f"{info['device']} x {jax.local_device_count()}: device counts {args.devices}, "
        f"{args.envs_per_device:,} envs per device, config {args.config}",
        flush=True,
    )
    rows = run_all(args, info, lambda rows: benchmarks.scaling.report.write_all(args.out_dir, stem, rows, meta))
    paths = benchmarks.scaling.report.write_all(args.out_dir, stem, rows, meta)
    print(benchmarks.scaling.report.markdown(rows, meta))
    print("wrote " + ", ".join(str(p) for p in paths), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

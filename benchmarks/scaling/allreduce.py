"""Time the all-reduces of one PPO iteration on the devices of every process that joins.

    python -m benchmarks.scaling.allreduce [--config configs/train_flat.yaml] [--repeats 5] [--out FILE [--append]]
        [--coordinator HOST:PORT --num-processes N --process-id I]   # or srun / mpirun, as the trainer

Each process runs the same command (flags, ``HSA_*`` variables or a cluster launcher, as
``python -m train``). The iteration's all-reduces (:mod:`benchmarks.scaling.network_cost` counts them on a
CPU: ``rounds`` rounds of ``bytes / rounds`` bytes each, the gradient's mean once per minibatch
step) run as one ``pmap``-ed ``lax.scan`` of ``psum``s over every device of every process, so each
round waits for the last, as the minibatch steps do. Timed after a warm-up call, the median of
``--repeats``; the same for one 4-byte round (the latency) and for the iteration's bytes in one
round (the bandwidth). With NCCL's peer-to-peer and shared-memory transports turned off
(``NCCL_P2P_DISABLE=1 NCCL_SHM_DISABLE=1``) the GPUs of one host talk through NCCL's socket
transport, as GPUs on two hosts without InfiniBand do (over the host's TCP stack; on one host the
bytes never cross a wire). Process 0 prints and writes the result.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp

from benchmarks.run_info import report, run_info
from benchmarks.scaling import network_cost
from train import config as train_config
from train.devices import cluster
from train.devices.replicas import replicate
from train.learners.ppo.learner import AXIS

NCCL_VARS = ("NCCL_P2P_DISABLE", "NCCL_SHM_DISABLE", "NCCL_IB_DISABLE", "NCCL_NET", "NCCL_SOCKET_IFNAME")


def rounds_program(rounds: int):
    """A ``pmap``-ed scan of ``rounds`` all-reduces of its input, each fed by the last."""

    def body(x, _):
        return jax.lax.psum(x, AXIS) * (1.0 / jax.device_count()), None

    def run(x):
        return jax.lax.scan(body, x, None, length=rounds)[0]

    return jax.pmap(run, axis_name=AXIS)


def time_rounds(rounds: int, floats: int, repeats: int) -> float:
    """Median seconds of ``rounds`` all-reduces of ``floats`` float32 values over every device."""
    program = rounds_program(rounds)
    x = replicate(jnp.ones((max(1, floats),), jnp.float32), jax.local_devices())
    program(x).block_until_ready()  # compile and warm up NCCL's communicators
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        program(x).block_until_ready()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def measure(config_path: str, repeats: int) -> dict:
    """The iteration's all-reduces timed over every device, beside one-round latency and bandwidth."""
    config = train_config.load(config_path, ["run.collection=pmap", "env.physics.backend=jax"])
    counted = network_cost.per_iteration(config)["all-reduce"]
    rounds = int(round(counted["rounds"]))
    per_round = int(counted["bytes"] / max(1, rounds) / 4)
    iteration_s = time_rounds(rounds, per_round, repeats)
    latency_s = time_rounds(64, 1, repeats) / 64
    one_round_s = time_rounds(1, int(counted["bytes"] / 4), repeats)
    devices = jax.device_count()
    bus = 2 * (devices - 1) / devices * counted["bytes"] / one_round_s / 1e9  # NCCL's "bus bandwidth"
    return {
        "config": config_path,
        "devices": devices,
        "processes": jax.process_count(),
        "device_kind": jax.devices()[0].device_kind,
        "nccl": {v: os.environ[v] for v in NCCL_VARS if v in os.environ},
        "iteration": {"rounds": rounds, "bytes_per_round": per_round * 4, "seconds": iteration_s},
        "latency_s_per_round": latency_s,
        "one_round": {"bytes": int(counted["bytes"]), "seconds": one_round_s, "bus_gb_per_s": bus},
        "repeats": repeats,
        "run": run_info(),
    }


def to_markdown(result: dict) -> str:
    """One result as a Markdown table."""
    it, one = result["iteration"], result["one_round"]
    transport = ", ".join(f"{k}={v}" for k, v in result["nccl"].items()) or "NCCL defaults"
    return (
        "\n".join(
            [
                f"# All-reduces of one PPO iteration: `{result['config']}`",
                "",
                f"{result['devices']} x {result['device_kind']} in {result['processes']} processes; {transport}; "
                f"median of {result['repeats']}",
                "",
                *([result["note"], ""] if result.get("note") else []),
                "| what | bytes | time |",
                "|---|---|---|",
                f"| the iteration: {it['rounds']} rounds of {it['bytes_per_round']:,} B | "
                f"{it['rounds'] * it['bytes_per_round']:,} | {it['seconds'] * 1e3:,.1f} ms |",
                f"| one 4-byte round (latency) | 4 | {result['latency_s_per_round'] * 1e6:,.1f} us |",
                f"| the iteration's bytes in one round | {one['bytes']:,} | {one['seconds'] * 1e3:,.1f} ms "
                f"({one['bus_gb_per_s']:.1f} GB/s bus bandwidth) |",
            ]
        )
        + "\n"
    )


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="configs/train_flat.yaml", help="training YAML (its iteration is timed)")
    p.add_argument("--repeats", type=int, default=5, help="timed calls after the warm-up (the median is kept)")
    p.add_argument("--out", type=Path, default=None, help="process 0 writes FILE.json and FILE.md")
    p.add_argument("--append", action="store_true", help="add this result to what --out's files hold")
    p.add_argument("--note", default="", help="where and how it was measured (kept in the files)")
    p.add_argument("--coordinator", default=None, metavar="HOST:PORT", help="as python -m train")
    p.add_argument("--num-processes", type=int, default=None, metavar="N")
    p.add_argument("--process-id", type=int, default=None, metavar="I")
    args = p.parse_args(argv)
    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    if not Path(args.config).is_file():
        raise FileNotFoundError(f"no config at {args.config}")
    cluster.initialize(cluster.resolve_spec(args.coordinator, args.num_processes, args.process_id))
    result = {**measure(args.config, args.repeats), "note": args.note}
    if jax.process_index() == 0:
        report(args.out, result, to_markdown(result), append=args.append)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

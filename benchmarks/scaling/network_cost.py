"""What the GPUs exchange in one PPO iteration, and what that would cost over a network.

    python -m benchmarks.scaling.network_cost [--config configs/train_flat.yaml] [--gpus 8,64]
        [--links-gbps 100,400] [--latency-us 5] [--iteration-s S] [--out FILE [--append]]

Traces the learner's epoch with its device axis (nothing runs; a CPU does) and adds up every
collective in it per iteration: the calls, the bytes each GPU puts in, and what for (the
gradient's mean per minibatch, the observation statistics, the goal curriculum's gather of every
env's episode ends). Each GPU steps the config's ``run.num_envs``. Then it projects the time
those collectives take on N GPUs joined by links of a given speed, with the ring algorithm's
costs: an all-reduce of b bytes sends 2 (N - 1) / N x b and waits 2 (N - 1) link latencies, an
all-gather sends (N - 1) x b and waits N - 1 latencies; the latencies are counted once per round
(all the collectives of one loop body merged, as XLA's combiners can). ``--iteration-s`` (one iteration's time
on one GPU) turns the times into a share of the iteration. A projection, not a measurement:
NCCL's tree algorithms, overlap with compute and congestion all move it.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np
from jax.extend.core import ClosedJaxpr, Jaxpr

from benchmarks.run_info import report
from hsa_mjx.curricula import goal_curriculum
from train import config as train_config
from train.devices import strategies
from train.learners.ppo.learner import AXIS
from train.learners.ppo.networks import init_training_state

ALL_REDUCE = {"psum", "psum2", "psum_invariant", "pmax", "pmin"}
ALL_GATHER = {"all_gather", "all_gather_invariant"}


def _sub_jaxprs(params: dict) -> list[Jaxpr]:
    """The jaxprs an equation's parameters hold (a scan's body, a cond's branches, a call's jaxpr)."""
    found = []
    for value in params.values():
        for item in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(item, ClosedJaxpr):
                found.append(item.jaxpr)
            elif isinstance(item, Jaxpr):
                found.append(item)
    return found


def _empty_count() -> dict:
    return {kind: {"calls": 0.0, "rounds": 0.0, "bytes": 0.0} for kind in ("all-reduce", "all-gather")}


def count_collectives(jaxpr: Jaxpr, times: float = 1.0, out: dict | None = None) -> dict:
    """{kind: {"calls", "rounds", "bytes"}} of every collective in ``jaxpr``, each counted as often as
    it runs (a scan's body ``length`` times, a cond's heaviest branch; a while loop's body once,
    flagged). ``calls`` as traced (JAX binds one per array); ``rounds`` as XLA's combiner can merge
    them at best: one per kind per loop body and run."""
    out = _empty_count() if out is None else out
    seen = set()
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        kind = "all-reduce" if name in ALL_REDUCE else "all-gather" if name in ALL_GATHER else None
        if kind:
            out[kind]["calls"] += times
            out[kind]["rounds"] += 0 if kind in seen else times
            out[kind]["bytes"] += times * sum(np.prod(v.aval.shape) * v.aval.dtype.itemsize for v in eqn.invars)
            seen.add(kind)
            continue
        subs = _sub_jaxprs(eqn.params)
        if name == "cond":
            counted = [count_collectives(s, times) for s in subs]
            heaviest = max(counted, key=lambda c: sum(k["bytes"] for k in c.values()))
            for k, fields in _empty_count().items():
                for field in fields:
                    out[k][field] += heaviest[k][field]
            continue
        for sub in subs:
            before = sum(k["calls"] for k in out.values())
            count_collectives(sub, times * (eqn.params["length"] if name == "scan" else 1), out)
            if name == "while" and sum(k["calls"] for k in out.values()) > before:
                out["inside_while"] = True  # counted once per loop, not per trip
    return out


def per_iteration(config: train_config.TrainConfig) -> dict:
    """The collectives of one PPO iteration on each GPU (calls and bytes in, per kind); ``config``
    with ``run.collection`` ``pmap`` (the learner with its device axis)."""
    strategy = strategies.build(config, jax.local_devices()[:1])
    learner = strategy.learner
    ts = init_training_state(config, learner.networks, jax.random.PRNGKey(0), learner.network_input_size)
    goal = goal_curriculum.init(config.goal_curriculum, tuple(config.env.goal.radial_range))
    keys = jax.ShapeDtypeStruct((learner.env.num_envs, 2), np.uint32)
    state = jax.eval_shape(lambda k: learner.reset(k, goal, None), keys)
    traced = jax.make_jaxpr(learner.epoch, axis_env=[(AXIS, 2)])(ts, state, jax.ShapeDtypeStruct((2,), np.uint32))
    counted = count_collectives(traced.jaxpr)
    iterations = learner.iterations_per_epoch
    return {
        kind: {field: value / iterations for field, value in v.items()}
        for kind, v in counted.items()
        if isinstance(v, dict)
    } | {"inside_while": counted.get("inside_while", False)}


def project(collectives: dict, gpus: int, gbps: float, latency_s: float) -> float:
    """Seconds the collectives of one iteration take on ``gpus`` GPUs over ``gbps`` links (ring algorithm)."""
    rate = gbps * 1e9 / 8  # bytes per second
    reduce, gather = collectives["all-reduce"], collectives["all-gather"]
    reduce_s = 2 * (gpus - 1) / gpus * reduce["bytes"] / rate + 2 * (gpus - 1) * latency_s * reduce["rounds"]
    gather_s = (gpus - 1) * gather["bytes"] / rate + (gpus - 1) * latency_s * gather["rounds"]
    return reduce_s + gather_s


def run(args: argparse.Namespace) -> dict:
    """Count, project, and return the result (written by :func:`main`)."""
    config = train_config.load(args.config, ["run.collection=pmap"])
    collectives = per_iteration(config)
    rows = []
    for gpus in args.gpus:
        for gbps in args.links_gbps:
            seconds = project(collectives, gpus, gbps, args.latency_us * 1e-6)
            share = seconds / args.iteration_s if args.iteration_s else None
            rows.append({"gpus": gpus, "link_gbps": gbps, "seconds_per_iteration": seconds, "share": share})
    return {
        "config": str(args.config),
        "envs_per_gpu": config.run.num_envs,
        "env_steps_per_iteration_per_gpu": config.env_steps_per_iteration,
        "latency_us": args.latency_us,
        "iteration_s": args.iteration_s,
        "per_iteration": collectives,
        "projection": rows,
    }


def to_markdown(result: dict) -> str:
    """The counts and the projection as Markdown."""
    per = result["per_iteration"]
    lines = [
        f"# Collectives of one PPO iteration: `{result['config']}`, {result['envs_per_gpu']:,} envs per GPU",
        "",
        "| collective | calls as traced | rounds (merged per loop body) | bytes in per GPU |",
        "|---|---|---|---|",
        *(
            f"| {k} | {per[k]['calls']:,.0f} | {per[k]['rounds']:,.0f} | {per[k]['bytes']:,.0f} |"
            for k in ("all-reduce", "all-gather")
        ),
        "",
        f"Projection (ring algorithm, {result['latency_us']} us a link hop, one latency per round"
        + (f", one iteration {result['iteration_s']} s on one GPU):" if result["iteration_s"] else "):"),
        "",
        "| GPUs | link | collectives per iteration | share of an iteration |",
        "|---|---|---|---|",
    ]
    for row in result["projection"]:
        share = f"{100 * row['share']:.1f} %" if row["share"] is not None else "-"
        lines.append(
            f"| {row['gpus']} | {row['link_gbps']:g} Gb/s | {row['seconds_per_iteration'] * 1e3:,.1f} ms | {share} |"
        )
    return "\n".join(lines) + "\n"


def _numbers(text: str, kind: type) -> list:
    """A comma list of numbers (ValueError naming the text when it is not one)."""
    try:
        return [kind(v) for v in text.split(",") if v]
    except ValueError as err:
        raise ValueError(f"expected a comma list of numbers, got {text!r}") from err


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="configs/train_flat.yaml", help="training YAML")
    p.add_argument("--gpus", type=lambda t: _numbers(t, int), default=[8, 64], help="comma list of GPU counts")
    p.add_argument("--links-gbps", type=lambda t: _numbers(t, float), default=[100.0, 400.0], help="link speeds")
    p.add_argument("--latency-us", type=float, default=5.0, help="one hop's latency (an assumption)")
    p.add_argument("--iteration-s", type=float, default=None, help="one iteration's time on one GPU (measured)")
    p.add_argument("--out", type=Path, default=None, help="write FILE.json and FILE.md")
    p.add_argument("--append", action="store_true", help="add this result to what --out's files hold")
    args = p.parse_args(argv)
    if any(g < 2 for g in args.gpus):
        raise ValueError(f"--gpus must all be >= 2, got {args.gpus}")
    result = run(args)
    report(args.out, result, to_markdown(result), append=args.append)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

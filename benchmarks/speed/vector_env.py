"""Env-steps/s of the Gymnasium vector env (numpy and JAX outputs) against the env's own jitted batched step.

Every mode makes one Python call per env step of the whole batch, as a Gymnasium learner does:

- ``jit_step``: ``jax.jit(AutoResetEnv.step)``, the env's own batched step with per-env
  auto-reset, on actions drawn beforehand on the device; calls are dispatched asynchronously and
  synchronised once at the end (the most a Python loop over single steps can get).
- ``vector_jax``: ``HSAVectorEnv.step`` (``make_vec(..., output="jax")``) on device actions, JAX
  outputs, with its finiteness check of the actions (one bool read from the device per step).
- ``vector_jax_nocheck``: the same with ``check_finite=False`` (no host round trip at all).
- ``vector_numpy``: the default ``make_vec`` env (``NumpyOutput``) on numpy actions: actions sent
  to the device, every output (obs, reward, flags, the info arrays) copied back as numpy.
- ``vector_torch``: the JAX-output env in Gymnasium's ``JaxToTorch`` (torch tensors through
  DLPack, on the GPU when torch sees one) on torch actions; left out, with a message, where torch
  is not installed (it is no dependency of this package).

Physics: the shipped setting of the scene (``benchmarks.fidelity.guard.SHIPPED_BY_SCENE``) unless
``--setting`` names another. Per batch and mode: one warm-up call (the compile), then ``--repeats``
runs of ``--steps`` steps; the median is reported. Results: ``--out``.json (rows and provenance:
date, device, versions, command, git commit) and ``--out``.md, rewritten after every batch.

    python -m benchmarks.speed.vector_env --batches 4096,16384 [--steps 100] [--repeats 3] [--scene flat|terrain]
        [--setting NAME] [--modes ...] [--out benchmarks/results/throughput/vector_env_<device>]
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from benchmarks.fidelity.guard import SETTINGS, SHIPPED_BY_SCENE
from benchmarks.run_info import run_info
from benchmarks.speed.report import slug
from hsa_mjx.adapters.gymnasium_vector import HSAVectorEnv, NumpyOutput
from hsa_mjx.batch.auto_reset import AutoResetEnv

MODES = ("jit_step", "vector_jax", "vector_jax_nocheck", "vector_numpy", "vector_torch")
HEAD = ["batch", "mode", "env_steps_per_s", "ms_per_step", "vs_jit_step", "first_call_s", "steps", "repeats"]
ACTION_SETS = 4  # distinct random action batches, cycled


def timed_runs(step: Callable[[int], Any], steps: int, repeats: int) -> tuple[float, list[float]]:
    """(seconds of the warm-up call, seconds of each run of ``steps`` calls); ``step(i)`` returns outputs."""
    tic = time.perf_counter()
    jax.block_until_ready(step(0))
    first = time.perf_counter() - tic
    runs = []
    for _ in range(repeats):
        tic = time.perf_counter()
        out = None
        for i in range(steps):
            out = step(i)
        jax.block_until_ready(out)
        runs.append(time.perf_counter() - tic)
    return first, runs


def mode_steps(envs: HSAVectorEnv, seed: int = 0) -> dict[str, Callable[[int], Any]]:
    """One step function per mode over the same envs (``jit_step`` on its own batch state)."""
    shape = envs.action_space.shape
    host = [np.random.default_rng(seed + k).uniform(-1, 1, shape).astype(np.float32) for k in range(ACTION_SETS)]
    device = [jax.device_put(a) for a in host]
    batch = AutoResetEnv(envs.env)
    jitted = jax.jit(batch.step)
    numpy_envs = NumpyOutput(envs)
    envs.reset(seed=seed)
    state = {"batch": jax.jit(batch.reset)(jax.random.split(jax.random.PRNGKey(seed), envs.num_envs))}

    def jit_step(i: int) -> Any:
        state["batch"] = jitted(state["batch"], device[i % ACTION_SETS])
        return state["batch"].env.obs

    def vector(check: bool) -> Callable[[int], Any]:
        def step(i: int) -> Any:
            envs.check_finite = check
            return envs.step(device[i % ACTION_SETS])

        return step

    steps = {
        "jit_step": jit_step,
        "vector_jax": vector(True),
        "vector_jax_nocheck": vector(False),
        "vector_numpy": lambda i: numpy_envs.step(host[i % ACTION_SETS]),
    }
    torch_step = torch_steps(envs, host)
    if torch_step is not None:
        steps["vector_torch"] = torch_step
    return steps


def torch_steps(envs: HSAVectorEnv, host: list[np.ndarray]) -> Callable[[int], Any] | None:
    """The ``vector_torch`` step (Gymnasium's JaxToTorch around the JAX-output env), or None without torch."""
    try:
        import torch
        from gymnasium.wrappers.vector import JaxToTorch
    except ImportError as err:
        print(f"vector_torch left out: {err}", flush=True)
        return None
    device = "cuda" if torch.cuda.is_available() else "cpu"
    torch_envs = JaxToTorch(envs, device=device)
    actions = [torch.as_tensor(a, device=device) for a in host]

    def step(i: int) -> Any:
        envs.check_finite = True
        torch_envs.step(actions[i % ACTION_SETS])
        if device == "cuda":
            torch.cuda.synchronize()
        return None

    return step


def measure_batch(
    batch: int, overrides: dict[str, Any], steps: int, repeats: int, modes: tuple[str, ...]
) -> list[dict[str, Any]]:
    """Rows for one batch size, every mode."""
    envs = HSAVectorEnv(batch, **overrides)
    rows, base = [], None
    for mode, step in mode_steps(envs).items():
        if mode not in modes:
            continue
        try:
            first, runs = timed_runs(step, steps, repeats)
        except Exception as err:
            rows.append({"batch": batch, "mode": mode, "error": f"{type(err).__name__}: {err}"[:300]})
            print(rows[-1], flush=True)
            continue
        seconds = statistics.median(runs)
        rate = batch * steps / seconds
        base = rate if mode == "jit_step" else base
        rows.append(
            {
                "batch": batch,
                "mode": mode,
                "env_steps_per_s": round(rate),
                "ms_per_step": round(1000 * seconds / steps, 3),
                "vs_jit_step": round(rate / base, 3) if base else None,
                "first_call_s": round(first, 2),
                "steps": steps,
                "repeats": repeats,
            }
        )
        print(rows[-1], flush=True)
    envs.close()
    del envs
    gc.collect()
    return rows


def default_out() -> Path:
    """benchmarks/results/throughput/vector_env_<device> (e.g. vector_env_nvidia_h200)."""
    return Path("benchmarks/results/throughput") / f"vector_env_{slug(jax.devices()[0].device_kind)}"


def markdown(caption: str, rows: list[dict[str, Any]], meta: dict[str, Any], columns: list[str] = HEAD) -> str:
    """The caption, a table of ``rows`` (an ``error`` column where a mode failed) and the provenance line."""
    head = columns + (["error"] if any("error" in r for r in rows) else [])
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    lines += ["| " + " | ".join(str(r.get(k, "-")) for k in head) + " |" for r in rows]
    return "\n".join([caption, "", *lines, "", f"{meta['date']}, {meta['device']}, command `{meta['command']}`", ""])


def write_results(
    out: Path, caption: str, rows: list[dict[str, Any]], started: float, columns: list[str] = HEAD
) -> None:
    """``out``.json (provenance and rows) and ``out``.md, each written to a temporary file and renamed."""
    meta = {**run_info(), "wall_s": round(time.perf_counter() - started, 1)}
    out.parent.mkdir(parents=True, exist_ok=True)
    texts = {
        ".json": json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n",
        ".md": markdown(caption, rows, meta, columns),
    }
    for suffix, text in texts.items():
        tmp = out.with_suffix(suffix + ".tmp")
        tmp.write_text(text)
        os.replace(tmp, out.with_suffix(suffix))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.speed.vector_env",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--batches", default="4096,16384", help="comma-separated batch sizes")
    p.add_argument("--steps", type=int, default=100, help="env steps per timed run")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--scene", choices=sorted(SHIPPED_BY_SCENE), default="flat")
    p.add_argument("--setting", choices=sorted(SETTINGS), default=None, help="physics setting (default: shipped)")
    p.add_argument("--modes", default=",".join(MODES), help=f"comma-separated subset of {list(MODES)}")
    p.add_argument("--out", type=Path, default=None, help="result stem: writes .json and .md")
    args = p.parse_args(argv)
    batches = [int(b) for b in args.batches.split(",") if b]
    modes = tuple(m for m in args.modes.split(",") if m)
    if not batches or min(batches) < 1 or args.steps < 1 or args.repeats < 1:
        p.error("--batches, --steps and --repeats must be positive")
    if set(modes) - set(MODES):
        p.error(f"unknown mode(s) {sorted(set(modes) - set(MODES))}; modes: {list(MODES)}")
    setting = args.setting or SHIPPED_BY_SCENE[args.scene]
    overrides = {"scene": args.scene, **{k.replace(".", "__"): v for k, v in SETTINGS[setting].items()}}
    tic = time.perf_counter()
    caption = (
        f"Gymnasium vector env against the jitted batched step: {args.scene} scene, physics "
        f"`{setting}`, one Python call per env step, median of {args.repeats} runs of {args.steps} steps."
    )
    rows: list[dict[str, Any]] = []
    for batch in batches:  # the results are rewritten after every batch: a run cut short keeps them
        rows += measure_batch(batch, overrides, args.steps, args.repeats, modes)
        write_results(args.out or default_out(), caption, rows, tic)
    print(markdown(caption, rows, run_info()), flush=True)


if __name__ == "__main__":
    main()

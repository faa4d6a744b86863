"""MuJoCo Warp's kernels for an env built in a helper process, beside a training start's XLA compile.

A cold start on the Warp backend builds two sets of kernels: the modules :func:`hsa_mjx.sim.warp_kernels.prebuild`
compiles ahead, and the kernels MuJoCo Warp makes for the model's sizes at their first launch (Cholesky
tiles, height-field collision: 25 s on the plane and 78 s on terrain on one H200, one after another).
Stepped on a thread of the training process while XLA compiled the epoch, the second set took 35 s and
the compile three times its time alone: the two overlap little in one process.

:func:`start` launches ``python -m hsa_mjx.task.warp_builder`` on the same GPU with the env's config: it
builds the env (the model, the data, the prebuild), then every kernel module a step loads at once: a
dry run of the step names them and threads compile them together
(:func:`hsa_mjx.sim.warp_kernels.build_for_model`; stepped for real, the second set compiled one after
another in 46 s on an H200). It writes every kernel to Warp's kernel cache on disk and reports its seconds
as one JSON line. The
training process meanwhile builds its env, its first state and the epoch's program, then waits for the
helper's report (:meth:`Builder.wait`) before the first epoch, whose kernels then load from the cache in
milliseconds. The helper allocates GPU memory as it needs it (no preallocation). A failure is a warning:
the first epoch then builds what is missing, as without the helper.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import jax


@dataclass
class Builder:
    """A running helper process and its output, read as it comes by :meth:`follow` on a thread."""

    process: subprocess.Popen
    launched_at: float  # wall clock (time.time(): the helper's report uses the same clock)
    lines: list[str] = field(default_factory=list)
    report: dict[str, Any] | None = None  # its output's last report line, parsed
    reported: threading.Event = field(default_factory=threading.Event)  # its report came, or its output ended
    reader: threading.Thread | None = None  # runs follow

    def follow(self) -> None:
        """Read the helper's output to its end, flag its report as soon as it comes, then reap it."""
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))
            report = _report(line)
            if report is not None:
                self.report = report
                self.reported.set()
        self.reported.set()
        self.process.wait()

    def wait(self, timeout_s: float = 600.0) -> dict[str, Any] | None:
        """Wait for the helper's report, not its exit (killed past ``timeout_s``, several times a cold
        terrain build's 2 min): the report (``prebuild_s``, ``warm_up_s`` and ``modules`` in it, ``done_s``
        from its launch to its report, ``waited_s`` in this call), or None with a warning (its output's
        tail) when it failed."""
        start = time.perf_counter()
        if not self.reported.wait(timeout_s):
            self.process.kill()
        report = dict(self.report) if self.report is not None else None
        if report is None or report.get("warm_up_s") is None:
            self.reader.join()  # its whole output read and the process reaped
            code = self.process.returncode
            tail = " | ".join(self.lines[-4:])
            warnings.warn(f"the Warp kernel helper failed (exit {code}: {tail}); they build at first use", stacklevel=2)
            return None
        done_s = report.pop("finished_at") - self.launched_at
        return {**report, "done_s": round(done_s, 3), "waited_s": round(time.perf_counter() - start, 3)}


def watch(process: subprocess.Popen, launched_at: float) -> Builder:
    """A :class:`Builder` for a helper launched with its output on a text pipe, read on a daemon thread."""
    builder = Builder(process, launched_at)
    builder.reader = threading.Thread(target=builder.follow, name="warp-helper-output", daemon=True)
    builder.reader.start()
    return builder


def _report(line: str) -> dict | None:
    """A line of the helper's output as its report (a JSON object with ``finished_at``), else None."""
    if not line.startswith("{"):
        return None
    try:
        report = json.loads(line)
    except json.JSONDecodeError:
        return None
    return report if isinstance(report, dict) and "finished_at" in report else None


def _visible_devices(device: jax.Device | None) -> str | None:
    """``CUDA_VISIBLE_DEVICES`` for a helper on ``device`` (its CUDA ordinal in this process's view), or
    None to inherit this process's (no device given)."""
    if device is None:
        return None
    seen = os.environ.get("CUDA_VISIBLE_DEVICES")
    ordinal = device.local_hardware_id
    if seen:
        names = [name.strip() for name in seen.split(",") if name.strip()]
        return names[ordinal] if ordinal < len(names) else None
    return str(ordinal)


def spawn(env_config: dict, num_envs: int, device: jax.Device | None = None) -> Builder:
    """Launch the helper for the env ``env_config`` (``hsa_mjx.config.to_dict``) sized for ``num_envs``,
    on ``device`` (None: wherever this process's defaults put it)."""
    env = {**os.environ, "XLA_PYTHON_CLIENT_PREALLOCATE": "false", "PYTHONUNBUFFERED": "1"}
    visible = _visible_devices(device)
    if visible is not None:
        env["CUDA_VISIBLE_DEVICES"] = visible
    launched = time.time()
    process = subprocess.Popen(
        [sys.executable, "-m", "hsa_mjx.task.warp_builder"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=env,
        text=True,
    )
    process.stdin.write(json.dumps({"env": env_config, "num_envs": num_envs}))
    process.stdin.close()
    return watch(process, launched)


def start(env_config: dict, num_envs: int, physics: str, device: jax.Device) -> Builder | None:
    """The helper for a training start whose env runs on ``physics`` (resolved) on ``device``: launched
    only for MJX's Warp backend on a GPU (None elsewhere: nothing worth a process)."""
    if physics != "warp" or device.platform != "gpu":
        return None
    try:
        return spawn(env_config, num_envs, device)
    except OSError as err:
        warnings.warn(f"the Warp kernel helper did not start ({err}); the kernels build in this process", stacklevel=2)
        return None


def main() -> int:
    """The helper: read ``{"env": ..., "num_envs": ...}`` from stdin, build that env and its step's kernels,
    print the seconds as one JSON line."""
    request = json.loads(sys.stdin.read())
    from hsa_mjx.config import from_dict
    from hsa_mjx.sim import warp_kernels
    from hsa_mjx.task.env import HSAEnv

    env = HSAEnv(from_dict(request["env"]), num_envs=int(request["num_envs"]))
    warm_up_s = env.warm_up_physics(all_at_once=True)  # this process's results are discarded
    prebuilt = sum(warp_kernels.build_seconds.values())
    modules = sum(warp_kernels.model_modules.values())
    report = {"prebuild_s": round(prebuilt, 3), "warm_up_s": warm_up_s, "modules": modules, "finished_at": time.time()}
    print(json.dumps(report), flush=True)
    return 0 if warm_up_s is not None else 1


if __name__ == "__main__":
    sys.exit(main())

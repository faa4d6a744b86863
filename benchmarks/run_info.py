"""Provenance recorded with every benchmark result: date, machine, device, versions, command."""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import jax


# environment variables that change speed or numerics: recorded with every result
SPEED_ENV_VARS = ("XLA_FLAGS", "JAX_DEFAULT_MATMUL_PRECISION", "CUDA_VISIBLE_DEVICES", "JAX_ENABLE_X64")


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo (Linux), else platform.processor()."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def versions() -> dict[str, str | None]:
    """Versions of the packages the numbers depend on."""
    return {name: _version(name) for name in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "brax", "numpy")}


def device_kind() -> str:
    """What JAX runs on, e.g. 'NVIDIA H200' or 'cpu'."""
    return str(jax.devices()[0].device_kind)


def git_state() -> dict[str, Any]:
    """Commit of the checkout and whether it had local changes (None outside a git checkout)."""
    def git(*args: str) -> str | None:
        try:
            out = subprocess.run(["git", *args], capture_output=True, text=True, timeout=10, check=True)
        except (OSError, subprocess.SubprocessError):
            return None
        return out.stdout.strip()
    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain") if commit else None
    return {"git_commit": commit, "git_dirty": None if status is None else bool(status)}


def run_info() -> dict[str, Any]:
    """Date (UTC), host, CPU, JAX backend and device, versions and the command line."""
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "host": platform.node(),
        "cpu": cpu_name(),
        "cpu_count": os.cpu_count(),
        "backend": jax.default_backend(),
        "device": device_kind(),
        "device_count": jax.device_count(),
        "versions": versions(),
        "python": platform.python_version(),
        "command": "python -m " + _module_name() + " " + shlex.join(sys.argv[1:]),
        "environment": {name: os.environ.get(name) for name in SPEED_ENV_VARS},
        **git_state(),
    }


def _module_name() -> str:
    """Dotted module name of the running script (``benchmarks.fidelity``), or its path."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    return spec.name if spec is not None else (sys.argv[0] if sys.argv else "python")


def write_table_result(out: Path, table: str, rows: list[dict], started: float) -> dict[str, Any]:
    """Print ``table``; write ``out``.json (provenance and rows) and ``out``.md (table, date, device, command)."""
    print(table)
    info = {**run_info(), "wall_s": round(time.perf_counter() - started, 1)}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"meta": info, "rows": rows}, indent=1))
    out.with_suffix(".md").write_text(table + f"\n\n{info['date']}, {info['device']}, command `{info['command']}`\n")
    return info


def print_table(table: str, out: Path | None) -> int:
    """Print a markdown ``table``, also write it to ``out`` when given; return 0 (a CLI's exit code)."""
    print(table, flush=True)
    if out:
        out.write_text(table)
    return 0


def markdown_rows(rows: list[dict], head: list[str]) -> str:
    """A markdown table of ``rows`` with the columns ``head`` (one row per dict)."""
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    lines += ["| " + " | ".join(str(r[k]) for k in head) + " |" for r in rows]
    return "\n".join(lines)


def gait_sweep_cli(argv: list[str] | None, prog: str, doc: str, default_out: str,
                   sweep: Callable[[float], list[dict]], caption: Callable[[float], str], head: list[str]) -> None:
    """The command line of an open-loop gait sweep: ``--seconds`` per gait, ``--out`` the result's stem."""
    p = argparse.ArgumentParser(prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--out", type=Path, default=Path(default_out))
    args = p.parse_args(argv)
    tic = time.perf_counter()
    rows = sweep(args.seconds)
    write_table_result(args.out, caption(args.seconds) + "\n\n" + markdown_rows(rows, head), rows, tic)

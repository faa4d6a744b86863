"""Provenance recorded with every benchmark result: date, machine, device, versions, command."""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

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


def row_provenance(info: dict[str, Any]) -> dict[str, Any]:
    """The fields of :func:`run_info` every result row carries (``gpu``: the device name)."""
    return {
        "gpu": info["device"],
        "device_count": info["device_count"],
        "backend": info["backend"],
        "versions": info["versions"],
        "date": info["date"],
        "command": info["command"],
        "git_commit": info.get("git_commit"),
        "git_dirty": info.get("git_dirty"),
    }


def _module_name() -> str:
    """Dotted module name of the running script (``benchmarks.fidelity.guard``), or its path."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    return spec.name if spec is not None else (sys.argv[0] if sys.argv else "python")


def write_result(stem: Path, result: dict[str, Any], text: str, append: bool = False) -> None:
    """Write ``result`` to ``stem``.json and its markdown ``text`` to ``stem``.md (the folder made), and print
    the text. ``append``: keep what the files hold and add this result after it (the JSON becomes
    ``{"results": [...]}``, its earlier result first; the Markdown gets the text below the old)."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    print(text)
    json_path, md_path = stem.with_suffix(".json"), stem.with_suffix(".md")
    if append and json_path.is_file():
        old = json.loads(json_path.read_text())
        result = {"results": [*(old["results"] if set(old) == {"results"} else [old]), result]}
        text = (md_path.read_text().rstrip("\n") + "\n\n" if md_path.is_file() else "") + text
    json_path.write_text(json.dumps(result, indent=1, default=float) + "\n")
    md_path.write_text(text)


def report(out: Path | None, result: dict[str, Any], text: str, append: bool = False) -> None:
    """A tool's ``--out FILE [--append]``: :func:`write_result` beside ``out`` (its suffix dropped), or
    print ``text`` when no file is asked for."""
    if out is None:
        print(text)
    else:
        write_result(out.with_suffix(""), result, text, append=append)

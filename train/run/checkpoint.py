"""Checkpoints: learner, curriculum and step count as msgpack, with the config as JSON, written atomically.

Layout: ``RUN_DIR/checkpoints/step_<000000001234>/{state.msgpack, meta.json}``. A checkpoint is
written into a hidden temporary directory and renamed into place, so a killed run leaves either
the complete new checkpoint or none (older ones are untouched). Nothing is loaded with pickle:
arrays go through ``flax.serialization`` (msgpack) into a template built from the current config,
so a checkpoint of another shape is refused.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import serialization

FORMAT_VERSION = 1
STATE_FILE, META_FILE = "state.msgpack", "meta.json"
_NAME = re.compile(r"^step_(\d{12})$")
# Config keys that must match for a resume (the rest, e.g. run length or learning rate, may change).
COMPATIBLE_SECTIONS = ("env", "curriculum")
# Keys of those sections that may change on resume: which MJX implementation runs the same physics.
FREE_KEYS = ("env.physics.backend", "env.physics.contacts_per_env", "env.physics.constraints_per_env")


def checkpoint_dir(run_dir: str | Path) -> Path:
    """Where a run's checkpoints live."""
    return Path(run_dir) / "checkpoints"


def save(
    run_dir: str | Path, step: int, payload: dict[str, Any], config: dict, keep: int = 3, extra: dict | None = None
) -> Path:
    """Write checkpoint ``step`` atomically and keep only the newest ``keep``; return its path.

    ``extra``: more metadata for ``meta.json`` (e.g. the physics backend the run used).
    """
    root = checkpoint_dir(run_dir)
    root.mkdir(parents=True, exist_ok=True)
    final = root / f"step_{step:012d}"
    host = jax.tree.map(np.asarray, jax.device_get(payload))
    data = serialization.msgpack_serialize(serialization.to_state_dict(host))
    meta = {"format": FORMAT_VERSION, "step": int(step), "config": config, **(extra or {})}
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp_{final.name}_", dir=root))
    try:
        (tmp / STATE_FILE).write_bytes(data)
        (tmp / META_FILE).write_text(json.dumps(meta, indent=1))
        for f in (tmp / STATE_FILE, tmp / META_FILE):
            with open(f, "rb") as fh:
                os.fsync(fh.fileno())
        if final.exists():  # re-saving the same step (e.g. Ctrl-C right after a save)
            shutil.rmtree(final)
        os.replace(tmp, final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    _prune(root, keep)
    return final


def _prune(root: Path, keep: int) -> None:
    """Delete all but the newest ``keep`` checkpoints."""
    for old in list_checkpoints(root.parent)[:-keep]:
        shutil.rmtree(old, ignore_errors=True)


def list_checkpoints(run_dir: str | Path) -> list[Path]:
    """Complete checkpoints of a run, oldest first."""
    root = checkpoint_dir(run_dir)
    if not root.is_dir():
        return []
    found = [p for p in root.iterdir() if p.is_dir() and _NAME.match(p.name)]
    return sorted(found, key=lambda p: int(_NAME.match(p.name).group(1)))


def latest(run_dir: str | Path) -> Path:
    """The newest checkpoint of a run (FileNotFoundError naming the directory if none)."""
    found = list_checkpoints(run_dir)
    if not found:
        raise FileNotFoundError(
            f"no checkpoint found in {checkpoint_dir(run_dir)} (expected directories named step_<12 digits>)"
        )
    return found[-1]


def latest_readable(run_dir: str | Path) -> tuple[Path, list[str]]:
    """The newest checkpoint whose metadata and state decode, and why each newer one was skipped.

    A crash while a checkpoint is written leaves no partial one (temp dir + rename), but a disk
    fault or a hand edit can; resuming then falls back to the newest good one instead of failing.
    """
    skipped = []
    for path in reversed(list_checkpoints(run_dir)):
        try:
            read_meta(path)
            serialization.msgpack_restore((path / STATE_FILE).read_bytes())
            return path, skipped
        except Exception as err:  # msgpack raises several unrelated types on garbage
            skipped.append(f"{path.name}: {type(err).__name__}: {err}")
    raise FileNotFoundError(
        f"no readable checkpoint in {checkpoint_dir(run_dir)}"
        + (f" (unreadable: {skipped})" if skipped else " (expected directories named step_<12 digits>)")
    )


def read_meta(path: str | Path) -> dict:
    """The JSON metadata of a checkpoint directory (ValueError if missing or corrupt)."""
    path = Path(path)
    try:
        meta = json.loads((path / META_FILE).read_text())
    except FileNotFoundError as err:
        raise FileNotFoundError(f"checkpoint {path} has no {META_FILE}") from err
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"checkpoint {path} is corrupt: {META_FILE} is not valid JSON ({err})") from err
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_VERSION or "config" not in meta:
        raise ValueError(
            f"checkpoint {path}: unsupported or corrupt metadata (format {meta.get('format')!r}, "
            f"expected {FORMAT_VERSION})"
        )
    return meta


def load(path: str | Path, template: dict[str, Any]) -> dict[str, Any]:
    """Restore a payload saved by :func:`save` into the structure of ``template`` (host arrays)."""
    path = Path(path)
    state_file = path / STATE_FILE
    if not state_file.is_file():
        raise FileNotFoundError(f"checkpoint {path} has no {STATE_FILE}")
    try:
        raw = serialization.msgpack_restore(state_file.read_bytes())
    except Exception as err:  # msgpack raises several unrelated types on garbage
        raise ValueError(
            f"checkpoint {state_file} is corrupt and cannot be decoded ({type(err).__name__}: {err})"
        ) from err
    host_template = jax.tree.map(np.asarray, jax.device_get(template))
    try:
        restored = serialization.from_state_dict(host_template, raw)
    except (ValueError, KeyError, TypeError) as err:
        raise ValueError(f"checkpoint {path} does not match this config's networks/state: {err}") from err
    _check_shapes(host_template, restored, path)
    return restored


def _check_shapes(template: Any, restored: Any, path: Path) -> None:
    """Every restored array must have the template's shape and dtype kind."""
    for (where, want), got in zip(jax.tree_util.tree_leaves_with_path(template), jax.tree.leaves(restored)):
        got = np.asarray(got)
        if np.shape(want) != got.shape:
            raise ValueError(
                f"checkpoint {path} does not match this config: {jax.tree_util.keystr(where)} "
                f"has shape {got.shape}, expected {np.shape(want)}"
            )


def incompatibilities(saved: dict, current: dict, defaults: dict | None = None) -> list[str]:
    """Config keys whose change makes a checkpoint unusable for resuming (empty list: compatible).

    A key the saved config lacks (added to the code after the checkpoint was written) is
    compatible when its current value equals its value in ``defaults`` (the default config).
    """
    defaults = defaults or {}
    problems = []
    for section in COMPATIBLE_SECTIONS:
        problems += [
            f"{section}.{k}"
            for k in _diff(saved.get(section, {}), current.get(section, {}), defaults.get(section, {}))
            if f"{section}.{k}" not in FREE_KEYS
        ]
    from ..learners.registry import LEARNERS  # deferred: reading a checkpoint's files needs no learner

    learners = [c.get("run", {}).get("learner", "ppo") for c in (saved, current)]
    if learners[0] != learners[1]:  # another learner's state
        problems.append("run.learner")
    for learner in LEARNERS.values():  # the keys each learner's networks are built from
        was, now, default = (c.get(learner.NAME, {}) for c in (saved, current, defaults))
        problems += [f"{learner.NAME}.{k}" for k in learner.NETWORK_KEYS if was.get(k, default.get(k)) != now.get(k)]
    return problems


_ABSENT = object()


def _diff(a: Any, b: Any, default: Any = _ABSENT, prefix: str = "") -> list[str]:
    """Dotted keys where two nested dicts differ (a key missing from ``a`` matches ``default``)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        default = default if isinstance(default, dict) else {}
        for key in sorted(set(a) | set(b)):
            d = default.get(key, _ABSENT)
            if key not in a and key in b and d is not _ABSENT and b[key] == d:
                continue
            out += _diff(a.get(key), b.get(key), d, f"{prefix}{key}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]

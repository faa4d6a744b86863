"""A run directory: what a run writes there, and the checks before it starts or resumes.

A run dir holds ``config.yaml``, ``checkpoints/``, ``metrics.jsonl``, ``tensorboard/``,
``summary.json``, ``learning_curve.png``, the learner's ``ppo_diagnostics.png`` or ``td3_diagnostics.png``
and, under SLURM, ``job.json`` (the job that started it). A new run refuses a folder that already holds
one (``--overwrite`` replaces the run's own files, nothing else), unless it is the same SLURM job,
requeued before its first checkpoint: that run starts afresh (``train.devices.cluster``). A resume reads
the newest readable checkpoint's metadata and refuses one written with a config whose networks, env or
curricula differ.
Every check runs before anything compiles; with several processes, process 0 alone writes.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import yaml

from ..config import TrainConfig, from_dict, to_dict
from ..devices import cluster, distributed
from . import checkpoint


def portable(path: Path, base: Path | None = None) -> str:
    """``path`` as a result file records it: relative to ``base`` (default: the working directory) when
    inside it, else its name alone, so no file carries a machine's absolute paths."""
    path, base = Path(path).absolute(), Path(base if base is not None else Path.cwd()).absolute()
    return str(path.relative_to(base)) if path.is_relative_to(base) else path.name


RUN_FILES = (
    "checkpoints",
    "metrics.jsonl",
    "tensorboard",
    "config.yaml",
    "summary.json",
    "learning_curve.png",
    "ppo_diagnostics.png",
    "td3_diagnostics.png",
    "job.json",
)
JOB_FILE = "job.json"


def run_files(run_dir: Path) -> list[str]:
    """What a run left in ``run_dir`` (its own file names only)."""
    return [name for name in RUN_FILES if (run_dir / name).exists()]


def _current_keys(saved: dict) -> dict:
    """A saved config with older keys mapped onto the current ones (as loading it does); as saved when
    it no longer loads (the comparison then names what differs)."""
    try:
        return json.loads(json.dumps(to_dict(from_dict(saved))))
    except (ValueError, TypeError):
        return saved


def prepare_run_dir(run_dir: Path, config_dict: dict, resume: bool, overwrite: bool = False) -> dict | None:
    """Create the run dir (process 0), refuse to write into another run's files, and read the checkpoint
    to resume (the newest readable one; before any compile). When one process refuses, all stop."""
    refused = meta = None
    requeued = _requeued_before_a_checkpoint(run_dir)
    try:
        if resume and not requeued:
            meta = _resume_meta(run_dir, config_dict)
        else:
            _start_run_dir(run_dir, config_dict, overwrite or requeued)
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
    marker = cluster.job_marker()
    if marker:
        (run_dir / JOB_FILE).write_text(json.dumps(marker))
    return None


def _requeued_before_a_checkpoint(run_dir: Path) -> bool:
    """Whether the run in ``run_dir`` is this SLURM job's own, requeued before it wrote a checkpoint: it
    then starts afresh (a new run would be refused, a resume would find nothing to resume)."""
    if checkpoint.list_checkpoints(run_dir) or not (run_dir / JOB_FILE).is_file():
        return False
    try:
        marker = json.loads((run_dir / JOB_FILE).read_text())
    except (OSError, json.JSONDecodeError):
        return False
    requeued = cluster.restarted_job(marker)
    if requeued and distributed.is_main():
        print(f"{run_dir}: this SLURM job, requeued before its first checkpoint: starting afresh", flush=True)
    return requeued


def _resume_meta(run_dir: Path, config_dict: dict) -> dict:
    """The newest readable checkpoint's metadata (and ``path``), refused when its config differs."""
    path, skipped = checkpoint.latest_readable(run_dir)
    for reason in skipped:
        print(f"warning: skipping unreadable checkpoint {reason}", flush=True)
    if skipped:
        print(f"resuming from the newest readable checkpoint, {path.name}", flush=True)
    meta = checkpoint.read_meta(path)
    now = json.loads(json.dumps(config_dict))
    defaults = json.loads(json.dumps(to_dict(TrainConfig())))
    bad = checkpoint.incompatibilities(_current_keys(meta["config"]), now, defaults)
    if bad:
        raise ValueError(
            f"checkpoint {path} was written with a different config; these keys differ: {bad}. "
            f"Resume with the run's own config ({run_dir / 'config.yaml'}) or start a new run dir."
        )
    meta["path"] = path
    return meta

"""Training logs: a progress line with env-steps/s and ETA, JSONL records and TensorBoard scalars."""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, TextIO

HEADLINE = ("episode/success_rate", "episode/return", "curriculum/max_distance", "episode/final_distance")


class ProgressBar:
    """A one-line text progress bar on a terminal (plain lines when not a terminal).

    The rate and ETA count from the first update on: the first epoch's time holds the compile,
    which would make the first ETA several times too long (its line says ``compiled``).
    """

    def __init__(self, total: int, start: int = 0, stream: TextIO = sys.stderr, width: int = 28):
        self.total, self.start, self.stream, self.width = total, start, stream, width
        self.t0 = time.perf_counter()
        self.first: tuple[float, int] | None = None  # (time, step) of the first update
        self.tty = stream.isatty()

    def update(self, step: int, extra: dict[str, float]) -> str:
        """Redraw for ``step`` with a few headline numbers; returns the line."""
        now = time.perf_counter()
        if self.first is None:
            self.first = (now, step)
            rate, eta = 0.0, math.nan  # the compile is in this interval
        else:
            elapsed = now - self.first[0]
            rate = (step - self.first[1]) / elapsed if elapsed > 0 else 0.0
            eta = max(0, self.total - step) / rate if rate > 0 else math.inf
        frac = min(step / self.total, 1.0) if self.total else 1.0
        bar = "#" * int(frac * self.width) + "-" * (self.width - int(frac * self.width))
        fields = " ".join(f"{k.split('/')[-1]} {v:.3g}" for k, v in extra.items())
        speed = "compiled" if math.isnan(eta) else f"{rate:,.0f} env-steps/s"
        line = f"[{bar}] {step:,}/{self.total:,} {100 * frac:5.1f}% | {speed} | ETA {_duration(eta)} | {fields}"
        self.stream.write(("\r" + line + "\x1b[K") if self.tty else line + "\n")
        self.stream.flush()
        return line

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


_IMPORTED = time.monotonic()


def process_age_s() -> float:
    """Seconds since this process was launched: from the kernel's process start time on Linux (so the
    interpreter's start and every import count), else since this module was imported."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")  # field 22: start time after boot, in ticks
        return float(Path("/proc/uptime").read_text().split()[0]) - started
    except (OSError, ValueError, IndexError):
        return time.monotonic() - _IMPORTED


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--:--"
    seconds = int(seconds)
    return f"{seconds // 3600:d}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


class MetricsLogger:
    """Append one JSON record per log to ``metrics.jsonl`` and mirror scalars to TensorBoard.

    ``resume_step``: the step of the checkpoint a resumed run starts from. Records a crashed run
    wrote after it are dropped from ``metrics.jsonl`` (rewritten atomically) and hidden in
    TensorBoard (its purge step), so the logs hold every step once and in order.
    """

    def __init__(self, run_dir: str | Path, tensorboard: bool = True, resume_step: int | None = None):
        self.path = Path(run_dir) / "metrics.jsonl"
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if resume_step is not None:
            truncate_after(self.path, resume_step)
        self.writer = None
        if tensorboard:
            try:
                from tensorboardX import SummaryWriter  # a Brax dependency

                purge = None if resume_step is None else resume_step + 1
                self.writer = SummaryWriter(str(Path(run_dir) / "tensorboard"), purge_step=purge)
            except ImportError:  # pragma: no cover - logged to JSONL only
                self.writer = None

    def log(self, step: int, metrics: dict[str, Any]) -> None:
        """Record ``metrics`` at env step ``step``."""
        record = {"step": int(step), "time": time.time(), **{k: _plain(v) for k, v in metrics.items()}}
        with self.path.open("a") as fh:
            fh.write(json.dumps(record) + "\n")
        if self.writer is not None:
            for key, value in record.items():
                if key not in ("step", "time") and isinstance(value, (int, float)) and math.isfinite(value):
                    self.writer.add_scalar(key, value, int(step))
            self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def _plain(value: Any) -> Any:
    try:
        return float(value)
    except (TypeError, ValueError):
        return value


def truncate_after(path: Path, step: int) -> int:
    """Keep the records of ``path`` up to ``step`` (and drop a truncated last line); returns how many
    were dropped. Written to a temp file and renamed: a crash here loses nothing."""
    if not path.is_file():
        return 0
    records = read_jsonl(path)
    kept = [r for r in records if int(r.get("step", 0)) <= step]
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in kept))
    os.replace(tmp, path)
    return len(records) - len(kept)


def read_jsonl(path: str | Path) -> list[dict]:
    """All records of a metrics file (skipping a truncated last line of a killed run)."""
    records = []
    for line in Path(path).read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records

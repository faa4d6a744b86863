"""Training logs: a progress line with env-steps/s and ETA, JSONL records and TensorBoard scalars."""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any, TextIO

HEADLINE = ("episode/success_rate", "episode/return", "curriculum/max_distance", "episode/final_distance")


class ProgressBar:
    """A one-line text progress bar on a terminal (plain lines when not a terminal)."""

    def __init__(self, total: int, start: int = 0, stream: TextIO = sys.stderr, width: int = 28):
        self.total, self.start, self.stream, self.width = total, start, stream, width
        self.t0 = time.perf_counter()
        self.tty = stream.isatty()

    def update(self, step: int, extra: dict[str, float]) -> str:
        """Redraw for ``step`` with a few headline numbers; returns the line."""
        elapsed = time.perf_counter() - self.t0
        rate = (step - self.start) / elapsed if elapsed > 0 else 0.0
        eta = (self.total - step) / rate if rate > 0 else math.inf
        frac = min(step / self.total, 1.0) if self.total else 1.0
        bar = "#" * int(frac * self.width) + "-" * (self.width - int(frac * self.width))
        fields = " ".join(f"{k.split('/')[-1]} {v:.3g}" for k, v in extra.items())
        line = (f"[{bar}] {step:,}/{self.total:,} {100 * frac:5.1f}% | {rate:,.0f} env-steps/s | "
                f"ETA {_duration(eta)} | {fields}")
        self.stream.write(("\r" + line + "\x1b[K") if self.tty else line + "\n")
        self.stream.flush()
        return line

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--:--"
    seconds = int(seconds)
    return f"{seconds // 3600:d}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


class MetricsLogger:
    """Append one JSON record per log to ``metrics.jsonl`` and mirror scalars to TensorBoard."""

    def __init__(self, run_dir: str | Path, tensorboard: bool = True):
        self.path = Path(run_dir) / "metrics.jsonl"
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.writer = None
        if tensorboard:
            try:
                from tensorboardX import SummaryWriter  # a Brax dependency
                self.writer = SummaryWriter(str(Path(run_dir) / "tensorboard"))
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


def read_jsonl(path: str | Path) -> list[dict]:
    """All records of a metrics file (skipping a truncated last line of a killed run)."""
    records = []
    for line in Path(path).read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records

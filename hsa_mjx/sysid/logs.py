"""Servo logs and test signals as CSV files: one row per control tick.

Columns: ``time`` (s, one control tick apart), ``target_0`` ... ``target_7`` (the commanded servo targets,
rad, in action-slot order: 1A, 2A, 3A, 4A, 1C, 2C, 3C, 4C) and, in a log, ``angle_0`` ... ``angle_7``
(the measured HSA-end angles, rad, read at that tick before its command). A test signal
(``python -m hsa_mjx.sysid signal``) has the targets alone; a log of it played on the robot adds the
angles. ``robots/example_log.csv`` is an example (``python -m hsa_mjx.sysid synth``'s output).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

SERVOS = 8
TARGETS = tuple(f"target_{i}" for i in range(SERVOS))
ANGLES = tuple(f"angle_{i}" for i in range(SERVOS))


@dataclasses.dataclass(frozen=True)
class ServoLog:
    """Commanded targets and, where measured, angles at each control tick."""

    dt: float  # s between rows
    targets: np.ndarray  # (ticks, 8) rad
    angles: np.ndarray | None = None  # (ticks, 8) rad, None for a test signal

    @property
    def seconds(self) -> float:
        """The log's length."""
        return self.dt * len(self.targets)


def write_log(path: str | Path, log: ServoLog) -> Path:
    """Write ``log`` as CSV (the header names the columns); returns the path."""
    path = Path(path)
    columns = [np.arange(len(log.targets)) * log.dt, *log.targets.T]
    header = ["time", *TARGETS]
    if log.angles is not None:
        columns += list(log.angles.T)
        header += ANGLES
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.stack(columns, axis=1), delimiter=",", header=",".join(header), comments="", fmt="%.6f")
    return path


def read_log(path: str | Path, need_angles: bool = True) -> ServoLog:
    """Read a signal or log CSV.

    Raises:
        FileNotFoundError: no such file.
        ValueError: a missing column (the message lists the expected ones), fewer than two rows,
            uneven or non-increasing times, or non-finite values.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"servo log not found: {path}")
    with path.open() as handle:
        header = handle.readline().strip().split(",")
    expected = ["time", *TARGETS, *(ANGLES if need_angles else ())]
    missing = [name for name in expected if name not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; a log has the columns {expected}")
    try:
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as err:
        raise ValueError(f"{path}: not a table of numbers under its header ({err})") from err
    if table.shape[0] < 2 or not np.all(np.isfinite(table)):
        raise ValueError(f"{path}: needs at least two rows of finite numbers")
    column = {name: table[:, header.index(name)] for name in header}
    steps = np.diff(column["time"])
    if not (steps.min() > 0 and np.allclose(steps, steps.mean(), rtol=1e-3, atol=1e-6)):
        raise ValueError(f"{path}: the time column must increase by one control tick a row")
    targets = np.stack([column[name] for name in TARGETS], axis=1)
    angles = np.stack([column[name] for name in ANGLES], axis=1) if all(a in column for a in ANGLES) else None
    return ServoLog(float(steps.mean()), targets, angles)

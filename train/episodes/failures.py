"""How each evaluated episode ended: reached, terminated (a termination reason), or, for an episode
that ran out of time, what the robot was doing at the end.

A time-out is told apart by the distance to the goal as the task measures it (``reward.progress``:
along the ground where the task uses the geodesic, so a robot rounding a bend of a corridor closes in)
over the episode's last ``window_s`` seconds (its start, for a shorter episode):

- ``stuck``: within ``stuck_m`` of where it was (it stopped making progress);
- ``lost``: at least ``stuck_m`` farther (it went the wrong way);
- ``slow``: at least ``stuck_m`` closer (still closing in: a longer episode would help).

Defaults ``window_s`` 20 s and ``stuck_m`` 0.1 m (``python -m train.evaluate --stuck-window-s
--stuck-distance-m``). Episodes still running at a step cap shorter than the episode limit count
as time-outs here.
"""

from __future__ import annotations

import dataclasses

import numpy as np

MODES = ("reached", "terminated", "stuck", "lost", "slow")
TIME_OUT_MODES = MODES[2:]


@dataclasses.dataclass(frozen=True)
class FailureRule:
    """The window and the distance that tell a time-out's mode."""

    window_s: float = 20.0
    stuck_m: float = 0.1

    def __post_init__(self):
        if not self.window_s > 0 or not self.stuck_m >= 0:
            raise ValueError(
                f"the failure modes need a window > 0 s and a distance >= 0 m (--stuck-window-s, "
                f"--stuck-distance-m), got {self.window_s} s and {self.stuck_m} m"
            )


DEFAULT_RULE = FailureRule()


def episode_modes(traces: dict[str, np.ndarray], dt: float, rule: FailureRule = DEFAULT_RULE) -> np.ndarray:
    """Each episode's mode (one of ``MODES``) from its traces (``train.episodes.rollout.rollout``'s:
    ``alive``, ``distance``, ``start_distance``, ``success``, ``reasons``)."""
    alive = traces["alive"].astype(bool)
    rows = np.arange(alive.shape[0])
    last = np.maximum(alive.sum(axis=1) - 1, 0)
    window = max(int(round(rule.window_s / dt)), 1)
    distance = np.asarray(traces["distance"])
    final = distance[rows, last]
    before = np.where(last >= window, distance[rows, np.maximum(last - window, 0)], traces["start_distance"])
    closer = before - final
    reached = traces["success"][rows, last] > 0.5
    terminated = (traces["reasons"][rows, last] > 0.5).any(axis=1)
    time_out = np.where(closer >= rule.stuck_m, "slow", np.where(closer <= -rule.stuck_m, "lost", "stuck"))
    return np.where(reached, "reached", np.where(terminated, "terminated", time_out))


def shares(modes: np.ndarray) -> dict[str, float]:
    """Each time-out mode's share of the episodes (``time_out/stuck`` ...), those that occur."""
    found = {f"time_out/{m}": float(np.mean(modes == m)) for m in TIME_OUT_MODES}
    return {k: v for k, v in found.items() if v > 0}


def mode_shares(modes: np.ndarray) -> dict[str, float]:
    """Every mode's share of the episodes, ``MODES`` in order (they add up to 1)."""
    return {m: float(np.mean(modes == m)) for m in MODES}

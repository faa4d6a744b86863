"""How evaluated episodes ended: made-up traces of each mode, and a U-bend where only the distance along the
ground says the robot is closing in."""

import numpy as np
import pytest

from hsa_mjx.task import termination
from train.episodes.failures import FailureRule, episode_modes, mode_shares, shares

T = 60  # steps of 1 s: the 20 s window is 20 steps


def _traces(distances: list[np.ndarray], ends: dict[int, int] | None = None, reason: int | None = None) -> dict:
    """Traces of episodes with these distances; ``ends``: episode -> its last step (it reached its goal);
    ``reason``: an episode that ended by a termination reason at its last step."""
    n = len(distances)
    alive, success = np.ones((n, T), bool), np.zeros((n, T))
    reasons = np.zeros((n, T, len(termination.REASONS)))
    for i, last in (ends or {}).items():
        alive[i, last + 1 :], success[i, last:] = False, 1.0
    if reason is not None:
        reasons[reason, -1, 0] = 1.0
    return {
        "alive": alive,
        "distance": np.stack(distances),
        "start_distance": np.array([d[0] for d in distances]),
        "success": success,
        "reasons": reasons,
    }


def test_time_outs_are_stuck_lost_or_slow_and_the_rest_reached_or_terminated():
    t = np.arange(T, dtype=float)
    jitter = 0.03 * np.sin(t)
    stuck = np.where(t < 30, 3.0 - 0.05 * t, 1.5) + jitter  # closed in, then stopped
    lost = np.where(t < 40, 3.0 - 0.05 * t, 1.0 + 0.05 * (t - 40))  # turned away at 40 s
    slow = 3.0 - 0.02 * t  # still closing in: 0.4 m over the last 20 s
    reached = np.maximum(3.0 - 0.2 * t, 0.1)
    broken = 3.0 - 0.05 * t
    traces = _traces([stuck, lost, slow, reached, broken], ends={3: 14}, reason=4)
    modes = episode_modes(traces, dt=1.0)
    assert list(modes) == ["stuck", "lost", "slow", "reached", "terminated"]
    assert shares(modes) == {"time_out/stuck": 0.2, "time_out/lost": 0.2, "time_out/slow": 0.2}
    assert sum(mode_shares(modes).values()) == pytest.approx(1.0)
    # the thresholds are options: a wider band calls the slow robot stuck
    assert episode_modes(traces, 1.0, FailureRule(window_s=20, stuck_m=0.5))[2] == "stuck"
    with pytest.raises(ValueError, match="--stuck-window-s"):
        FailureRule(window_s=0)


def test_rounding_a_bend_is_closing_in_along_the_ground():
    """A U-shaped corridor: east from (0, 0) to (2, 0), north to (2, 1), west to the goal at (0, 1), a wall
    between the two legs. Heading east, the robot moves away from the goal in a straight line but closes
    in along the corridor, the distance the task measures where it uses the geodesic."""
    x = np.linspace(0.0, 2.0, T)
    straight = np.hypot(x - 0.0, 0.0 - 1.0)
    along = (2.0 - x) + 1.0 + 2.0
    traces = _traces([along, straight])
    assert list(episode_modes(traces, dt=1.0)) == ["slow", "lost"]

"""Success rates with their uncertainty: the Wilson score interval of a binomial proportion.

Why Wilson: with 8 or 32 episodes a cell, the normal approximation (p +- 1.96 sqrt(p(1-p)/n)) gives
an interval of zero width at 0 % and 100 % and can leave [0, 1]; Wilson's stays inside and keeps a
width at the ends (8 of 8 successes: 68-100 %; 32 of 32: 89-100 %).
"""

from __future__ import annotations

import math

Z_95 = 1.959963984540054  # the standard normal's 97.5th percentile: a two-sided 95 % interval


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval (low, high) of ``successes`` in ``trials`` (ValueError on bad counts)."""
    if trials < 1 or not 0 <= successes <= trials:
        raise ValueError(f"need 0 <= successes <= trials and trials >= 1, got {successes} of {trials}")
    p, n, z2 = successes / trials, trials, z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    return max(0.0, centre - half), min(1.0, centre + half)

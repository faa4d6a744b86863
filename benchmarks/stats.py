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


def difference_interval(
    successes: tuple[int, int], trials: tuple[int, int], z: float = Z_95
) -> tuple[float, float, float]:
    """(difference, low, high) of two proportions, the first minus the second, with Newcombe's interval from
    their Wilson intervals (method 10 of Newcombe 1998: stays inside [-1, 1], keeps a width at 0 and 1)."""
    (s1, s2), (n1, n2) = successes, trials
    p1, p2 = s1 / n1, s2 / n2
    (l1, u1), (l2, u2) = wilson_interval(s1, n1, z), wilson_interval(s2, n2, z)
    d = p1 - p2
    return d, d - math.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2), d + math.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2)

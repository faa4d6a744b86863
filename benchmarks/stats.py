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


def paired_difference_interval(both: int, first_only: int, second_only: int, neither: int, z: float = Z_95):
    """(difference, low, high) of two proportions measured on the same episodes, the first minus the
    second, from the episodes' 2 x 2 table: Newcombe's interval for paired data (method 10 of Newcombe
    1998, "Improved confidence intervals for the difference between binomial proportions based on
    paired data"): the two Wilson intervals, combined with the correlation of the pairs, so that
    episodes both count alike narrow the interval (ValueError on bad counts)."""
    counts = (both, first_only, second_only, neither)
    if min(counts) < 0 or sum(counts) < 1:
        raise ValueError(f"need counts >= 0 and at least one pair, got {counts}")
    n = sum(counts)
    s1, s2 = both + first_only, both + second_only
    p1, p2 = s1 / n, s2 / n
    (l1, u1), (l2, u2) = wilson_interval(s1, n, z), wilson_interval(s2, n, z)
    margins = (both + first_only) * (second_only + neither) * (both + second_only) * (first_only + neither)
    phi = (both * neither - first_only * second_only) / math.sqrt(margins) if margins else 0.0
    d = p1 - p2
    below = (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2
    above = (u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2
    return d, max(-1.0, d - math.sqrt(max(below, 0.0))), min(1.0, d + math.sqrt(max(above, 0.0)))

"""What a log tells about each fitted figure: its 95 % error bound, and the pull of the held figures.

A fitted figure's bound is the wider of two measures:

- the **Fisher information**: the tracker's readings' derivatives with respect to the figures (central
  differences of ``STEP``) and the residual's variance; its inverse bounds each figure with the others
  free to trade off against it, exactly so for readings linear in the figures;
- the **error's profile**: the figure moved ``IDENTIFIABLE`` (5 %) away on each side, the others refitted
  (with the figure held, from the move the information says they make up for: Levenberg-Marquardt
  steps, then the evolution strategy shaped by the log's error ellipsoid, as the fit ends), and
  the error's rise there compared with the rise a 95 % interval allows (``PROFILE_LEVEL`` times the
  residual variance over the number of readings): the bound is 5 % times the square root of the level
  over the smaller rise (the error taken as quadratic), at most ``PROFILE_REACH`` times 5 %. A bound
  within 5 % thus says the error rises past the level at 5 % on both sides, whatever the derivatives
  claim. Friction makes the readings rough at small scale and bends the valleys where figures trade
  off, so the derivatives at the fit can claim more than the error's shape holds 5 % away.

The profile is measured only where the information alone would call a figure identifiable (a bound
within ``IDENTIFIABLE``): elsewhere the verdict is already "not identifiable" and a wider bound would
not change it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hsa_mjx.servo_config import ServoConfig
from hsa_mjx.sysid.search import (
    FITTED,
    HELD,
    LATENCY_UNIT,
    STEP,
    Evaluator,
    Search,
    jacobian,
    levenberg_marquardt,
    refine,
    score_points,
)

IDENTIFIABLE = 0.05  # a figure's 95 % bound (relative) must be this narrow for the log to identify it
PROFILE_LEVEL = 3.84  # chi-square of one degree of freedom at 95 %: the profile's allowed rise, in residual variances
PROFILE_STEPS = 3  # Levenberg-Marquardt derivatives refitting the other figures at each end of the profile,
PROFILE_GENERATIONS = 10  # then generations of the evolution strategy shaped by the log's information
PROFILE_REACH = 4.0  # the widest bound the profile reports, in IDENTIFIABLE (a rise this many squared times short)


def bounds(
    search: Search,
    x: np.ndarray,
    loss: float,
    latency_s: float,
    evaluate: Evaluator,
    profile: bool = True,
    step: float = STEP,
) -> dict[str, float]:
    """Each fitted figure's 95 % error bound relative to its value, from the log at ``x`` (the residual's
    variance ``loss``): the information's (central differences of ``step``), widened where the error's
    profile is flatter (``profile``)."""
    _, slopes = jacobian(search, x, latency_s, evaluate, step)  # the latency free too: its column last
    covariance = np.linalg.pinv(slopes.T @ slopes / max(loss, 1e-12))
    spread = 1.96 * np.sqrt(np.maximum(np.diag(covariance), 0.0))
    point, out = np.append(x, latency_s / LATENCY_UNIT), {}
    for i, name in enumerate(FITTED):
        width, edge = spread[i], IDENTIFIABLE / relative(search, x, name, 1.0)  # edge: 5 % in coordinates
        if profile and width <= edge:
            width = max(width, profile_width(search, point, loss, covariance, i, edge, evaluate))
        out[name] = relative(search, x, name, width)
    return out


def relative(search: Search, x: np.ndarray, name: str, width: float) -> float:
    """A width in the search's coordinates relative to the figure: log figures' are relative already; the
    dead band's (linear) against its size, at least a tenth of the search's unit."""
    if name != "deadband":
        return float(width)
    return float(width * search.scale / max(search.servo(x).deadband, 0.1 * search.scale))


def profile_width(
    search: Search,
    point: np.ndarray,
    loss: float,
    covariance: np.ndarray,
    index: int,
    width: float,
    evaluate: Evaluator,
) -> float:
    """The 95 % half-width of coordinate ``index`` by the error's profile, probed ``width`` away from
    ``point`` (figures' coordinates, then the latency) on each side: the flatter side's."""
    level = PROFILE_LEVEL * max(loss, 1e-12) / evaluate.log.angles.size
    along = covariance[:, index] / covariance[index, index]  # the others' first-order trade for this figure
    widths = []
    for sign in (1.0, -1.0):
        start = point + sign * width * along
        ((start_loss, latency_s),) = score_points(search, [start], evaluate)
        start[-1] = latency_s / LATENCY_UNIT
        start, refitted, normal = levenberg_marquardt(search, start, start_loss, evaluate, index, PROFILE_STEPS)
        _, refitted = refine(search, start, refitted, normal, evaluate, held=index, generations=PROFILE_GENERATIONS)
        rise = max(refitted - loss, 0.0) / level
        widths.append(width / np.sqrt(max(rise, PROFILE_REACH**-2)))
    return float(max(widths))


def held_pull(servo: ServoConfig, loss: float, evaluate: Evaluator) -> dict[str, float]:
    """The error's relative growth when each held figure moves 50 % up and down (0: the servo has none)."""
    present = [name for name in HELD if getattr(servo, name) > 0]
    moves = [(n, dataclasses.replace(servo, **{n: getattr(servo, n) * f})) for n in present for f in (1.5, 0.5)]
    scores = [s[0] for s in evaluate([m for _, m in moves])]
    return {
        name: float(np.mean([s for (n, _), s in zip(moves, scores) if n == name]) / max(loss, 1e-12) - 1.0)
        if getattr(servo, name) > 0
        else 0.0
        for name in HELD
    }

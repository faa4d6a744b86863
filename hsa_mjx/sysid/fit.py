"""Fit a profile's servo figures to a log of commanded targets and measured angles.

Each candidate set of figures is rolled out on the lifted rig in C MuJoCo with the log's targets
(``hsa_mjx.sysid.rig``: the env's own servo law, one process per core), its angles read at each tick
after the best latency (searched on a grid of substeps for every candidate), and scored by the mean
squared angle error. CMA-ES (``hsa_mjx.sysid.cmaes``) searches the figures in log scale around the
profile's (the data sheet's) values; Levenberg-Marquardt steps on the angles' derivatives finish the
search where figures trade off and the strategy closes in slowly, and a last evolution strategy shaped
by the log's own error ellipsoid follows the valleys where friction makes the derivatives rough. After
the fit, the log's information on each figure is measured (``hsa_mjx.sysid.information``: the Fisher
information, and the error's profile where friction makes the derivatives claim too much); a figure
whose 95 % bound is wider than ``IDENTIFIABLE`` is reported as not identifiable from this log, with its
bound, not silently kept. Gear play and the encoder's resolution are held at the profile's values; how
much a 50 % move of each changes the error is reported beside.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hsa_mjx.config import EnvConfig
from hsa_mjx.servo_config import ServoConfig, resolve_servo
from hsa_mjx.sysid.cmaes import CMAES
from hsa_mjx.sysid.information import IDENTIFIABLE, bounds, held_pull
from hsa_mjx.sysid.logs import ServoLog
from hsa_mjx.sysid.search import (  # noqa: F401  (re-exported: the fit's public names)
    FITTED,
    HELD,
    LATENCY_UNIT,
    MAX_LATENCY_S,
    POLISH_TOLERANCE,
    Evaluator,
    Search,
    at_supply,
    figure,
    gain_key,
    jacobian,
    levenberg_marquardt,
    refine,
    score_points,
)

SCANS = 4  # scans along the least determined directions, at most, each followed by more Levenberg-Marquardt
SCAN_MOVES = (-1.2, -0.6, -0.3, 0.3, 0.6, 1.2)  # a scan's moves, in the search's coordinates
SCAN_DIRECTIONS = 2  # the weakest directions each scan moves along
REFINE_GENERATIONS = 20  # the last stage: an evolution strategy shaped by the log's own information


@dataclasses.dataclass(frozen=True)
class FitResult:
    """The fitted servo, its error and latency, each fitted figure's 95 % bound and the held ones' pull."""

    servo: ServoConfig
    loss: float  # mean squared angle error, rad^2
    latency_s: float
    generations: int
    bound: dict[str, float]  # each fitted figure's 95 % error bound, relative to its value
    held: dict[str, float]  # the error's relative growth when a held figure moves 50 %
    history: list[float]  # best loss per generation

    def identifiable(self, name: str) -> bool:
        """Whether the log pins fitted figure ``name`` down (its 95 % bound within ``IDENTIFIABLE``)."""
        return self.bound[name] <= IDENTIFIABLE


def fit(
    config: EnvConfig,
    log: ServoLog,
    generations: int = 60,
    population: int = 12,
    seed: int = 0,
    workers: int | None = None,
    progress=None,
) -> FitResult:
    """Fit ``config``'s servo figures (``FITTED``) to ``log``, starting from them.

    Raises:
        ValueError: the log has no angles, its tick differs from the config's control tick, or the
            config's servos are the springs.
    """
    if log.angles is None:
        raise ValueError("fitting needs a log with measured angles (angle_0 ... angle_7), not a test signal")
    if not np.isclose(log.dt, config.dt, rtol=1e-3):
        raise ValueError(f"the log's tick is {log.dt:g} s, the profile's control tick {config.dt:g} s")
    if resolve_servo(config.servo) is None:
        raise ValueError("the spring servos have no figures to fit: choose a profile with DC-motor servos")
    search, evaluate = Search(config.servo), Evaluator(config, log, workers)
    try:
        x, loss, latency, history = _search(search, evaluate, generations, population, seed, progress)
        x, loss, latency = polish(search, x, loss, latency, evaluate)
        bound = bounds(search, x, loss, latency, evaluate)
        held = held_pull(search.servo(x), loss, evaluate)
    finally:
        evaluate.close()
    return FitResult(search.servo(x), loss, latency, len(history), bound, held, history + [loss])


def _search(search: Search, evaluate: Evaluator, generations: int, population: int, seed: int, progress) -> tuple:
    """CMA-ES from the profile's figures: the best (vector, loss, latency) and the best loss per generation."""
    es = CMAES(search.initial(), 0.3, population, seed)
    best, history = (search.initial(), np.inf, 0.0), []
    for _ in range(generations):
        xs = es.ask()
        scores = evaluate([search.servo(x) for x in xs])
        losses = np.array([score[0] for score in scores])
        es.tell(losses)
        i = int(np.argmin(losses))
        if losses[i] < best[1]:
            best = (xs[i], float(losses[i]), scores[i][1])
        history.append(best[1])
        if progress:
            progress(es.generation, best[1], es.sigma)
        if es.sigma < 1e-3:
            break
    return (*best, history)


def polish(search: Search, x: np.ndarray, loss: float, latency_s: float, evaluate: Evaluator) -> tuple:
    """Finish the search from its best: Levenberg-Marquardt steps (:func:`levenberg_marquardt`), then
    scans along the log's least determined directions (:func:`sloppy_scan`), each that finds a lower
    error followed by more steps (at most ``SCANS`` scans), then :func:`refine`. The search runs in the
    valley's coordinates (``Search(valley=True)``) with the latency moved beside the figures, off its grid
    (a latency a substep off holds the evolution strategy where other figures make up for it). Returns
    the best (vector in ``search``'s coordinates, loss, latency)."""
    figures, search = search, Search(search.start, valley=True)
    z = np.append(search.vector(figures.servo(x)), latency_s / LATENCY_UNIT)
    z, loss, normal = levenberg_marquardt(search, z, loss, evaluate)
    for _ in range(SCANS):
        z, loss, moved = sloppy_scan(search, z, loss, normal, evaluate)
        if not moved:
            break
        z, loss, normal = levenberg_marquardt(search, z, loss, evaluate)
    z, loss = refine(search, z, loss, normal, evaluate, generations=REFINE_GENERATIONS)
    return figures.vector(search.servo(z[:-1])), float(loss), float(z[-1] * LATENCY_UNIT)


def sloppy_scan(search: Search, z: np.ndarray, loss: float, normal: np.ndarray, evaluate: Evaluator) -> tuple:
    """Moves of ``SCAN_MOVES`` along each of the normal matrix's ``SCAN_DIRECTIONS`` weakest directions from
    ``z`` (where the error is flat to the derivatives but not in the large: friction makes it rough at
    small scale; the weakest can be a figure at its bound, such as a dead band of 0), the best of them if
    it lowers the error. (point, loss, whether it moved)."""
    weakest = np.linalg.eigh(normal)[1][:, :SCAN_DIRECTIONS].T
    trials = [z + move * direction for direction in weakest for move in SCAN_MOVES]
    scores = score_points(search, trials, evaluate)
    k = int(np.argmin([score[0] for score in scores]))
    if not scores[k][0] < loss * (1.0 - POLISH_TOLERANCE):
        return z, loss, False
    return np.append(trials[k][:-1], scores[k][1] / LATENCY_UNIT), scores[k][0], True

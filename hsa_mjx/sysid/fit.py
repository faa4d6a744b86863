"""Fit a profile's servo figures to a log of commanded targets and measured angles.

Each candidate set of figures is rolled out on the lifted rig in C MuJoCo with the log's targets
(``hsa_mjx.sysid.rig``: the env's own servo law, one process per core), its angles read at each tick
after the best latency (searched on a grid of substeps for every candidate), and scored by the mean
squared angle error. CMA-ES (``hsa_mjx.sysid.cmaes``) searches the figures in log scale around the
profile's (the data sheet's) values; a few Gauss-Newton steps on the angles' derivatives finish the
search where figures trade off and the strategy closes in slowly. After the fit, the log's information
on each figure is measured: the angles' derivatives with respect to the figures (central differences)
and the residual noise give the Fisher information, whose inverse bounds each figure's error with the
others free to trade off against it; a figure whose 95 % bound is wider than ``IDENTIFIABLE`` is
reported as not identifiable from this log, with its bound, not silently kept. Gear play and the
encoder's resolution are held at the profile's values; how much a 50 % move of each changes the error
is reported beside.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from hsa_mjx.config import EnvConfig
from hsa_mjx.servo_config import ServoConfig, resolve_servo
from hsa_mjx.sysid.cmaes import CMAES
from hsa_mjx.sysid.logs import ServoLog
from hsa_mjx.sysid.rig import measured, rig_rollout, substep_schedule

FITTED = ("stall_torque", "no_load_speed", "gain", "deadband", "damping", "friction", "armature")
HELD = ("backlash", "encoder_resolution")  # kept at the profile's values, their pull on the error reported
IDENTIFIABLE = 0.05  # a figure's 95 % bound (relative) must be this narrow for the log to identify it
STEP = 0.05  # the central differences' step in the search's coordinates (5 % of a figure)
POLISH_STEPS = 4  # Gauss-Newton steps after the evolution strategy
MAX_LATENCY_S = 0.1
# where the profile gives 0 for a figure, the search starts from this (per N m of stall torque for friction)
STARTS = {"damping": 0.01, "friction": 0.02, "armature": 1e-3}
DEADBAND_SCALE = {"position": 0.02, "continuous": 0.05}  # rad / share of full command, one unit of search


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


def gain_key(model: str) -> str:
    """The servo key behind the ``gain`` figure: kp (position) or speed_gain (continuous)."""
    return "kp" if model == "position" else "speed_gain"


def figure(servo: ServoConfig, name: str) -> float:
    """A fitted figure's value in ``servo`` (``gain``: its kp or speed gain, defaulted as the env does)."""
    if name == "gain":
        return float(getattr(resolve_servo(servo), gain_key(servo.model)))
    return float(getattr(servo, name))


def at_supply(servo: ServoConfig) -> ServoConfig:
    """``servo`` with its figures at its supply voltage (the voltage ratio folded in) and gains explicit."""
    params = resolve_servo(servo)
    volts = servo.voltage or servo.rated_voltage
    return dataclasses.replace(
        servo,
        stall_torque=params.stall_torque,
        no_load_speed=params.no_load_speed,
        kp=params.kp if servo.model == "position" else 0.0,
        speed_gain=params.speed_gain if servo.model == "continuous" else 0.0,
        voltage=volts,
        rated_voltage=volts,
    )


class Search:
    """The map between CMA-ES's vector and servo figures: log scale around ``start`` (the deadband linear)."""

    def __init__(self, start: ServoConfig):
        self.start = at_supply(start)
        self.scale = DEADBAND_SCALE[start.model]
        self.origin = {name: figure(self.start, name) for name in FITTED}
        for name, value in STARTS.items():
            if self.origin[name] <= 0:
                self.origin[name] = value * (self.start.stall_torque if name == "friction" else 1.0)

    def initial(self) -> np.ndarray:
        """The search's start: the profile's figures."""
        return np.array([self.origin["deadband"] / self.scale if n == "deadband" else 0.0 for n in FITTED])

    def servo(self, x: np.ndarray) -> ServoConfig:
        """The figures of vector ``x``."""
        values = {}
        for name, v in zip(FITTED, x):
            values[name] = max(v, 0.0) * self.scale if name == "deadband" else self.origin[name] * np.exp(v)
        if self.start.model == "continuous":
            values["deadband"] = min(values["deadband"], 0.9)
        values[gain_key(self.start.model)] = values.pop("gain")
        return dataclasses.replace(self.start, **{k: float(v) for k, v in values.items()})


def best_latency(angles: np.ndarray, log: ServoLog, frame_skip: int) -> tuple[float, float]:
    """(mean squared error, latency in s) at the best latency on the substep grid up to ``MAX_LATENCY_S``."""
    substep = log.dt / frame_skip
    best = (np.inf, 0.0)
    for k in range(int(round(MAX_LATENCY_S / substep)) + 1):
        error = float(np.mean((measured(angles, k * substep, log.dt, len(log.targets), frame_skip) - log.angles) ** 2))
        best = min(best, (error, k * substep))
    return best


_WORK: dict[str, Any] = {}


def _setup(config: EnvConfig, schedule: np.ndarray) -> None:
    _WORK.update(config=config, schedule=schedule)


def _angles(servo: ServoConfig) -> np.ndarray:
    return rig_rollout(dataclasses.replace(_WORK["config"], servo=servo), _WORK["schedule"])


def _score(servo: ServoConfig, log: ServoLog) -> tuple[float, float]:
    if not np.all(np.isfinite(angles := _angles(servo))):
        return np.inf, 0.0
    return best_latency(angles, log, _WORK["config"].control.frame_skip)


def _read(servo: ServoConfig, log: ServoLog, latency_s: float) -> np.ndarray:
    frame_skip = _WORK["config"].control.frame_skip
    return measured(_angles(servo), latency_s, log.dt, len(log.targets), frame_skip)


class Evaluator:
    """Scores candidate servos on ``log`` in parallel processes (``workers``; 1: in this process)."""

    def __init__(self, config: EnvConfig, log: ServoLog, workers: int | None = None):
        self.log, schedule = log, substep_schedule(log, config)
        self.workers = workers or os.cpu_count() or 1
        if self.workers == 1:
            _setup(config, schedule)
            self.pool = None
        else:
            context = multiprocessing.get_context("spawn")  # clean interpreters: no JAX state inherited
            self.pool = ProcessPoolExecutor(self.workers, context, initializer=_setup, initargs=(config, schedule))

    def __call__(self, servos: list[ServoConfig]) -> list[tuple[float, float]]:
        """Each servo's (mean squared error, latency) at its best latency."""
        return self._map(_score, servos, [self.log] * len(servos))

    def readings(self, servos: list[ServoConfig], latency_s: float) -> list[np.ndarray]:
        """Each servo's angles as the log's tracker reads them, ``latency_s`` late."""
        return self._map(_read, servos, [self.log] * len(servos), [latency_s] * len(servos))

    def _map(self, function, *columns) -> list:
        return list(map(function, *columns)) if self.pool is None else list(self.pool.map(function, *columns))

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()


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


def jacobian(search: Search, x: np.ndarray, latency_s: float, evaluate: Evaluator) -> tuple[np.ndarray, np.ndarray]:
    """The tracker's readings at ``x`` (flattened) and their derivatives with respect to the search's
    coordinates, (readings, figures), by central differences of ``STEP``."""
    moves = [x] + [x + sign * STEP * np.eye(len(x))[i] for i in range(len(x)) for sign in (1, -1)]
    readings = [r.ravel() for r in evaluate.readings([search.servo(m) for m in moves], latency_s)]
    return readings[0], np.stack([(readings[1 + 2 * i] - readings[2 + 2 * i]) / (2 * STEP) for i in range(len(x))], 1)


def polish(search: Search, x: np.ndarray, loss: float, latency_s: float, evaluate: Evaluator) -> tuple:
    """Gauss-Newton steps from the search's best, each tried whole, half and a quarter (the evolution
    strategy closes in slowly where figures trade off): the best (vector, loss, latency)."""
    for _ in range(POLISH_STEPS):
        centre, slopes = jacobian(search, x, latency_s, evaluate)
        step = np.linalg.lstsq(slopes, evaluate.log.angles.ravel() - centre, rcond=None)[0]
        trials = [x + share * step for share in (1.0, 0.5, 0.25)]
        scores = evaluate([search.servo(t) for t in trials])
        k = int(np.argmin([score[0] for score in scores]))
        if not scores[k][0] < loss:
            break
        x, (loss, latency_s) = trials[k], scores[k]
    return x, loss, latency_s


def bounds(search: Search, x: np.ndarray, loss: float, latency_s: float, evaluate: Evaluator) -> dict[str, float]:
    """Each fitted figure's 95 % error bound relative to its value, from the Fisher information of the log
    at ``x`` (the residual's variance ``loss``): the others free, so a trade-off between two figures
    widens both bounds."""
    _, slopes = jacobian(search, x, latency_s, evaluate)
    covariance = np.linalg.pinv(slopes.T @ slopes / max(loss, 1e-12))
    spread = 1.96 * np.sqrt(np.maximum(np.diag(covariance), 0.0))
    out = {}
    for i, name in enumerate(FITTED):  # log figures: relative already; the dead band: against its size
        size = max(search.servo(x).deadband, 0.1 * search.scale) if name == "deadband" else 1.0
        out[name] = float(spread[i] * (search.scale / size if name == "deadband" else 1.0))
    return out


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

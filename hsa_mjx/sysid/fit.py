"""Fit a profile's servo figures to a log of commanded targets and measured angles.

Each candidate set of figures is rolled out on the lifted rig in C MuJoCo with the log's targets
(``hsa_mjx.sysid.rig``: the env's own servo law, one process per core), its angles read at each tick
after the best latency (searched on a grid of substeps for every candidate), and scored by the mean
squared angle error. CMA-ES (``hsa_mjx.sysid.cmaes``) searches the figures in log scale around the
profile's (the data sheet's) values. After the fit, each figure is moved 10 % either way to measure
how much the error grows: a figure whose move changes the error by less than ``IDENTIFIABLE`` of it is
reported as not identifiable from this log (with its sensitivity), not silently kept. Gear play and the
encoder's resolution are held at the profile's values and reported with their sensitivity.
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
HELD = ("backlash", "encoder_resolution")  # kept at the profile's values, their sensitivity reported
IDENTIFIABLE = 0.01  # a 10 % move must change the mean squared error by at least this share
MAX_LATENCY_S = 0.1
# where the profile gives 0 for a figure, the search starts from this (per N m of stall torque for friction)
STARTS = {"damping": 0.01, "friction": 0.02, "armature": 1e-3}
DEADBAND_SCALE = {"position": 0.02, "continuous": 0.05}  # rad / share of full command, one unit of search


@dataclasses.dataclass(frozen=True)
class FitResult:
    """The fitted servo, its error, latency and each figure's sensitivity."""

    servo: ServoConfig
    loss: float  # mean squared angle error, rad^2
    latency_s: float
    generations: int
    sensitivity: dict[str, float]  # relative growth of the error for a 10 % move (held ones: 50 %)
    history: list[float]  # best loss per generation

    def identifiable(self, name: str) -> bool:
        """Whether the log pins figure ``name`` down (its sensitivity reaches ``IDENTIFIABLE``)."""
        return self.sensitivity[name] >= IDENTIFIABLE


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


def _score(servo: ServoConfig, log: ServoLog) -> tuple[float, float]:
    config = dataclasses.replace(_WORK["config"], servo=servo)
    if not np.all(np.isfinite(angles := rig_rollout(config, _WORK["schedule"]))):
        return np.inf, 0.0
    return best_latency(angles, log, config.control.frame_skip)


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
        logs = [self.log] * len(servos)
        return list(map(_score, servos, logs)) if self.pool is None else list(self.pool.map(_score, servos, logs))

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
        es = CMAES(search.initial(), 0.3, population, seed)
        best, history = (np.inf, 0.0, search.start), []
        for _ in range(generations):
            xs = es.ask()
            servos = [search.servo(x) for x in xs]
            scores = evaluate(servos)
            losses = np.array([s[0] for s in scores])
            es.tell(losses)
            i = int(np.argmin(losses))
            if losses[i] < best[0]:
                best = (float(losses[i]), scores[i][1], servos[i])
            history.append(best[0])
            if progress:
                progress(es.generation, best[0], es.sigma)
            if es.sigma < 1e-3:
                break
        sensitivity = sensitivities(best[2], best[0], evaluate)
    finally:
        evaluate.close()
    return FitResult(best[2], best[0], best[1], es.generation, sensitivity, history)


def sensitivities(servo: ServoConfig, loss: float, evaluate: Evaluator) -> dict[str, float]:
    """Each figure's relative growth of the error when moved 10 % up and down (held figures: 50 %; a zero
    dead band: by 10 % of its search unit)."""
    moves, names = [], []
    for name in FITTED + HELD:
        value, share = figure(servo, name), (0.5 if name in HELD else 0.1)
        if name in HELD and value == 0:  # the servo has none: nothing to move
            continue
        key = gain_key(servo.model) if name == "gain" else name
        step = value * share if value > 0 else DEADBAND_SCALE[servo.model] * share
        for sign in (1, -1):
            moves.append(dataclasses.replace(servo, **{key: max(value + sign * step, 0.0)}))
            names.append(name)
    scores = [s[0] for s in evaluate(moves)]
    out = {}
    for name in FITTED + HELD:
        pair = [score for n, score in zip(names, scores) if n == name]
        out[name] = float((np.mean(pair) - loss) / max(loss, 1e-12)) if pair else 0.0
    return out

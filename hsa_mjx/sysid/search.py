"""The servo fit's coordinates, its parallel scorer and its least-squares steps.

A candidate set of figures is rolled out on the lifted rig in C MuJoCo with the log's targets
(``hsa_mjx.sysid.rig``: the env's own servo law, one process per core), its angles read at each tick
after a latency, and scored by the mean squared angle error. ``Search`` maps the figures to a vector in
log scale around the profile's (the dead band linear); :func:`jacobian` gives the tracker's readings'
derivatives by central differences; :func:`levenberg_marquardt` steps on them, optionally with one
coordinate held (the error's profile along a figure, ``hsa_mjx.sysid.information``).
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
STEP = 0.05  # the central differences' step in the search's coordinates (5 % of a figure)
POLISH_STEPS = 12  # Levenberg-Marquardt derivatives after the evolution strategy, at most
POLISH_STEP = 0.05  # their central differences' step: wide enough to see past the small-scale roughness friction gives
POLISH_TOLERANCE = 1e-5  # a step must lower the mean squared error by this share, or the polish stops
REFINE_POPULATION = 10  # the evolution strategy shaped by the log's own information (:func:`refine`)
REFINE_SCALE = 2.0  # its first step: this many of the log's standard errors along its widest direction
MAX_LATENCY_S = 0.1
LATENCY_UNIT = 1e-3  # s: the latency's unit beside the figures' log scale in the derivatives
# where the profile gives 0 for a figure, the search starts from this (per N m of stall torque for friction)
STARTS = {"damping": 0.01, "friction": 0.02, "armature": 1e-3}
DEADBAND_SCALE = {"position": 0.02, "continuous": 0.05}  # rad / share of full command, one unit of search


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
    """The map between a search vector and servo figures: log scale around ``start`` (the dead band linear).

    With ``valley``, the no-load speed's coordinate holds the motor damping instead (stall torque / no-load
    speed + viscous damping, log scale): the log fixes that sum in any unsaturated motion much better than
    its split, and in these coordinates the valley of equal sums is straight (curved in the figures' own)."""

    def __init__(self, start: ServoConfig, valley: bool = False):
        self.start, self.valley = at_supply(start), valley
        self.scale = DEADBAND_SCALE[start.model]
        self.origin = {name: figure(self.start, name) for name in FITTED}
        for name, value in STARTS.items():
            if self.origin[name] <= 0:
                self.origin[name] = value * (self.start.stall_torque if name == "friction" else 1.0)
        self.motor_origin = self.origin["stall_torque"] / self.origin["no_load_speed"] + self.origin["damping"]

    def initial(self) -> np.ndarray:
        """The search's start: the profile's figures."""
        return np.array([self.origin["deadband"] / self.scale if n == "deadband" else 0.0 for n in FITTED])

    def servo(self, x: np.ndarray) -> ServoConfig:
        """The figures of vector ``x``."""
        values = {}
        for name, v in zip(FITTED, x):
            values[name] = max(v, 0.0) * self.scale if name == "deadband" else self.origin[name] * np.exp(v)
        if self.valley:
            motor = self.motor_origin * np.exp(x[FITTED.index("no_load_speed")])
            values["no_load_speed"] = values["stall_torque"] / max(motor - values["damping"], 1e-6 * motor)
        if self.start.model == "continuous":
            values["deadband"] = min(values["deadband"], 0.9)
        values[gain_key(self.start.model)] = values.pop("gain")
        return dataclasses.replace(self.start, **{k: float(v) for k, v in values.items()})

    def vector(self, servo: ServoConfig) -> np.ndarray:
        """The vector of ``servo``'s figures (``servo(vector(s))`` gives ``s`` back)."""
        x = np.array(
            [
                figure(servo, n) / self.scale if n == "deadband" else np.log(figure(servo, n) / self.origin[n])
                for n in FITTED
            ]
        )
        if self.valley:
            motor = servo.stall_torque / servo.no_load_speed + servo.damping
            x[FITTED.index("no_load_speed")] = np.log(motor / self.motor_origin)
        return x


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


def _score_at(servo: ServoConfig, log: ServoLog, latency_s: float) -> tuple[float, float]:
    if not np.all(np.isfinite(readings := _read(servo, log, latency_s))):
        return np.inf, latency_s
    return float(np.mean((readings - log.angles) ** 2)), latency_s


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

    def __call__(self, servos: list[ServoConfig], latencies: list[float] | None = None) -> list[tuple[float, float]]:
        """Each servo's (mean squared error, latency): at its best latency on the substep grid, or at
        its own of ``latencies``."""
        if latencies is None:
            return self._map(_score, servos, [self.log] * len(servos))
        return self._map(_score_at, servos, [self.log] * len(servos), latencies)

    def readings(self, servos: list[ServoConfig], latencies: list[float]) -> list[np.ndarray]:
        """Each servo's angles as the log's tracker reads them, its own of ``latencies`` late."""
        return self._map(_read, servos, [self.log] * len(servos), latencies)

    def _map(self, function, *columns) -> list:
        return list(map(function, *columns)) if self.pool is None else list(self.pool.map(function, *columns))

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()


def jacobian(
    search: Search, x: np.ndarray, latency_s: float, evaluate: Evaluator, step: float = STEP, held: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The tracker's readings at ``x`` (flattened) and their derivatives, (readings, figures + 1), with
    respect to the search's coordinates and, last, the latency in ``LATENCY_UNIT``: central differences
    of ``step``. With ``held``, that coordinate's column is left out."""
    n = len(x) + 1
    moves = [np.append(x, latency_s / LATENCY_UNIT)]
    columns = [i for i in range(n) if i != held]
    moves += [moves[0] + sign * step * np.eye(n)[i] for i in columns for sign in (1, -1)]
    servos, latencies = [search.servo(m[:-1]) for m in moves], [m[-1] * LATENCY_UNIT for m in moves]
    readings = [r.ravel() for r in evaluate.readings(servos, latencies)]
    slopes = [(readings[1 + 2 * k] - readings[2 + 2 * k]) / (2 * step) for k in range(len(columns))]
    return readings[0], np.stack(slopes, 1)


def score_points(search: Search, points: list[np.ndarray], evaluate: Evaluator) -> list[tuple[float, float]]:
    """(loss, latency) of each point (figures' coordinates, then the latency in ``LATENCY_UNIT``)."""
    latencies = [float(np.clip(p[-1] * LATENCY_UNIT, 0.0, MAX_LATENCY_S)) for p in points]
    return evaluate([search.servo(p[:-1]) for p in points], latencies)


def levenberg_marquardt(
    search: Search, z: np.ndarray, loss: float, evaluate: Evaluator, held: int | None = None, steps: int | None = None
) -> tuple:
    """Levenberg-Marquardt steps on the readings' residuals from ``z`` (figures' coordinates, latency):
    each tried at three dampings at once around the last that worked (a hundred times more, same
    derivatives, when none lowers the error by ``POLISH_TOLERANCE``), at most ``steps`` derivatives
    (``POLISH_STEPS``). Coordinate ``held``, if given, stays where it is. The best (point, loss) and the
    last derivatives' normal matrix (zero in the held coordinate's row and column)."""
    damping, free, normal = 1e-3, np.arange(len(z)) != (-1 if held is None else held), np.zeros((len(z), len(z)))
    for _ in range(POLISH_STEPS if steps is None else steps):
        centre, slopes = jacobian(search, z[:-1], z[-1] * LATENCY_UNIT, evaluate, POLISH_STEP, held)
        step_normal, gradient = slopes.T @ slopes, slopes.T @ (evaluate.log.angles.ravel() - centre)
        normal[np.ix_(free, free)] = step_normal
        while damping < 1e3:
            dampings = [damping * f for f in (0.1, 1.0, 10.0)]
            trials = [z.copy() for _ in dampings]
            for trial, d in zip(trials, dampings):
                trial[free] += np.linalg.solve(step_normal + d * np.diag(np.diag(step_normal) + 1e-12), gradient)
            scores = score_points(search, trials, evaluate)
            k = int(np.argmin([score[0] for score in scores]))
            if scores[k][0] < loss * (1.0 - POLISH_TOLERANCE):
                z, loss, damping = np.append(trials[k][:-1], scores[k][1] / LATENCY_UNIT), scores[k][0], dampings[k]
                break
            damping *= 100.0
        else:
            break
    return z, loss, normal


def refine(
    search: Search,
    z: np.ndarray,
    loss: float,
    normal: np.ndarray,
    evaluate: Evaluator,
    seed: int = 0,
    held: int | None = None,
    generations: int = 20,
) -> tuple:
    """CMA-ES from ``z`` whose first distribution is the log's own error ellipsoid (``loss`` times the
    inverse of the derivatives' ``normal`` matrix), ``REFINE_SCALE`` times as wide, the dead band held (a
    command level of the signal crossing it switches the servo on or off: a cliff no difference step may
    span) and coordinate ``held`` too, if given. It follows the curved valleys where friction leaves the
    derivatives too rough for Levenberg-Marquardt steps: ``generations``. The best (point, loss)."""
    if generations < 1:
        return z, loss
    free = np.array([name != "deadband" for name in FITTED] + [True]) & (np.arange(len(z)) != held)
    covariance = np.linalg.pinv(normal[np.ix_(free, free)]) * max(loss, 1e-12)
    widest = float(np.sqrt(np.max(np.diag(covariance))))
    es = CMAES(z[free], REFINE_SCALE * widest, REFINE_POPULATION, seed, covariance / widest**2)
    best = (z, loss)
    for _ in range(generations):
        points = [z.copy() for _ in range(REFINE_POPULATION)]
        for point, x in zip(points, es.ask()):
            point[free] = x
        scores = score_points(search, points, evaluate)
        es.tell(np.array([score[0] for score in scores]))
        k = int(np.argmin([score[0] for score in scores]))
        if scores[k][0] < best[1]:
            best = (np.append(points[k][:-1], scores[k][1] / LATENCY_UNIT), scores[k][0])
    return best

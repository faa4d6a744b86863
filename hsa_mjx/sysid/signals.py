"""The test signal a builder plays on the lifted robot: chirps of 0.1-10 Hz at several amplitudes, ramps
at constant speeds, then steps, the same on every servo, within the servos' range
(``python -m hsa_mjx.sysid signal``).

Chirps excite the servo's loop gain and rotor inertia across frequencies; large fast ones saturate the
drive and show the torque-speed line. Ramps hold the joint at a few constant speeds, where the loop's
lag is what the servo must overcome: a part that grows with speed (damping) and a part that does not
(friction), which only several speeds tell apart. Steps show the no-load speed and the stall against
the HSA's springs.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hsa_mjx.sysid.logs import SERVOS, ServoLog


@dataclasses.dataclass(frozen=True)
class SignalSpec:
    """What the signal plays (seconds, rad, Hz)."""

    chirp_amplitudes: tuple[float, ...] = (0.1, 0.4, 1.0)  # rad, one chirp each
    chirp_seconds: float = 10.0  # each chirp's length (the whole signal: 58.5 s)
    frequencies: tuple[float, float] = (0.1, 10.0)  # Hz, swept exponentially
    ramp_speeds: tuple[float, ...] = (0.5, 1.5, 3.0)  # rad/s, one triangle each: out, back and round
    ramp_amplitude: float = 1.5  # rad either side of the start
    steps: tuple[float, ...] = (0.3, -0.3, 1.0, -1.0, 2.0, -2.0)  # rad, each held step_seconds
    step_seconds: float = 1.5


def test_signal(spec: SignalSpec, dt: float, limit: float) -> ServoLog:
    """The targets at each control tick of ``dt`` s, within +-``limit`` rad (the servos' range).

    Raises:
        ValueError: an amplitude or step outside the range, or a frequency above the control rate's
            Nyquist frequency.
    """
    ramps = spec.ramp_amplitude if spec.ramp_speeds else 0.0
    largest = max((*spec.chirp_amplitudes, *(abs(s) for s in spec.steps), ramps))
    if largest > limit:
        raise ValueError(f"the signal reaches {largest:g} rad, outside the servos' range of +-{limit:g} rad")
    low, high = spec.frequencies
    if not 0 < low < high <= 0.5 / dt:
        raise ValueError(f"frequencies must satisfy 0 < low < high <= {0.5 / dt:g} Hz (half the control rate)")
    parts = [_chirp(a, spec.chirp_seconds, low, high, dt) for a in spec.chirp_amplitudes]
    parts += [_triangle(spec.ramp_amplitude, v, dt) for v in spec.ramp_speeds]
    parts += [np.full(int(round(spec.step_seconds / dt)), s) for s in spec.steps]
    parts.append(np.zeros(int(round(spec.step_seconds / dt))))  # back to the start
    wave = np.concatenate(parts)
    return ServoLog(dt, np.repeat(wave[:, None], SERVOS, axis=1))


def _triangle(amplitude: float, speed: float, dt: float) -> np.ndarray:
    """From 0 out to +amplitude, down to -amplitude and back to 0 at ``speed`` rad/s."""
    quarter = int(round(amplitude / speed / dt))
    up = np.arange(1, quarter + 1) * (amplitude / quarter)
    return np.concatenate([up, amplitude - up, -up, up - amplitude])


def _chirp(amplitude: float, seconds: float, low: float, high: float, dt: float) -> np.ndarray:
    """An exponential sweep from ``low`` to ``high`` Hz, starting and ending at 0."""
    t = np.arange(int(round(seconds / dt))) * dt
    rate = np.log(high / low) / seconds
    phase = 2.0 * np.pi * low * (np.exp(rate * t) - 1.0) / rate
    return amplitude * np.sin(phase) * np.sin(np.pi * t / seconds) ** 0.25  # a soft start and end

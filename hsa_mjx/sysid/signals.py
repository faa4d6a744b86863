"""The test signal a builder plays on the lifted robot: chirps of 0.1-10 Hz at several amplitudes, then
steps, the same on every servo, within the servos' range (``python -m hsa_mjx.sysid signal``).

Chirps excite the servo's loop gain, damping and rotor inertia across frequencies (their small-amplitude
part stays inside the dead band's reach); large fast ones saturate the drive and show the torque-speed
line; steps show the no-load speed, the stall against the HSA's springs and friction's hold.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hsa_mjx.sysid.logs import SERVOS, ServoLog


@dataclasses.dataclass(frozen=True)
class SignalSpec:
    """What the signal plays (seconds, rad, Hz)."""

    chirp_amplitudes: tuple[float, ...] = (0.1, 0.4, 1.0)  # rad, one chirp each
    chirp_seconds: float = 14.0  # each chirp's length (the whole signal: 59.5 s)
    frequencies: tuple[float, float] = (0.1, 10.0)  # Hz, swept exponentially
    steps: tuple[float, ...] = (0.3, -0.3, 1.0, -1.0, 2.0, -2.0)  # rad, each held step_seconds
    step_seconds: float = 2.5


def test_signal(spec: SignalSpec, dt: float, limit: float) -> ServoLog:
    """The targets at each control tick of ``dt`` s, within +-``limit`` rad (the servos' range).

    Raises:
        ValueError: an amplitude or step outside the range, or a frequency above the control rate's
            Nyquist frequency.
    """
    largest = max(max(spec.chirp_amplitudes, default=0.0), max((abs(s) for s in spec.steps), default=0.0))
    if largest > limit:
        raise ValueError(f"the signal reaches {largest:g} rad, outside the servos' range of +-{limit:g} rad")
    low, high = spec.frequencies
    if not 0 < low < high <= 0.5 / dt:
        raise ValueError(f"frequencies must satisfy 0 < low < high <= {0.5 / dt:g} Hz (half the control rate)")
    parts = [_chirp(a, spec.chirp_seconds, low, high, dt) for a in spec.chirp_amplitudes]
    parts += [np.full(int(round(spec.step_seconds / dt)), s) for s in spec.steps]
    parts.append(np.zeros(int(round(spec.step_seconds / dt))))  # back to the start
    wave = np.concatenate(parts)
    return ServoLog(dt, np.repeat(wave[:, None], SERVOS, axis=1))


def _chirp(amplitude: float, seconds: float, low: float, high: float, dt: float) -> np.ndarray:
    """An exponential sweep from ``low`` to ``high`` Hz, starting and ending at 0."""
    t = np.arange(int(round(seconds / dt))) * dt
    rate = np.log(high / low) / seconds
    phase = 2.0 * np.pi * low * (np.exp(rate * t) - 1.0) / rate
    return amplitude * np.sin(phase) * np.sin(np.pi * t / seconds) ** 0.25  # a soft start and end

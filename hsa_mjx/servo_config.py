"""``env.servo``: which servo model the robot's eight servos follow and its figures. The model itself:
``hsa_mjx.sim.servo``; named sets of figures from real hardware: the robot profiles (``hsa_mjx.robots``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

MODELS = ("spring", "position", "continuous")
MIXED = "mixed"  # ServoParams.model of envs that each draw a robot of either DC-motor model
# Full drive at this target error (rad) unless kp or speed_gain is given: a servo's loop gain is a
# setting, not a data-sheet figure.
SATURATION_ERROR = 0.1
KGF_CM = 0.0980665  # N m
RPM = 2.0 * math.pi / 60.0  # rad/s
# the figures of a DC-motor servo, in the order of ServoParams (each >= 0)
FIGURES = (
    "stall_torque",
    "no_load_speed",
    "kp",
    "speed_gain",
    "deadband",
    "damping",
    "friction",
    "armature",
    "backlash",
    "encoder_resolution",
)


@dataclasses.dataclass(frozen=True)
class ServoConfig:
    """``env.servo``: the servo model and its figures (a robot profile sets them all, ``env.robot``)."""

    model: str = "spring"  # spring (the asset's), position or continuous
    stall_torque: float = 0.0  # N m at rated_voltage
    no_load_speed: float = 0.0  # rad/s at rated_voltage
    kp: float = 0.0  # position: N m per rad of target error (0: stall_torque / SATURATION_ERROR)
    speed_gain: float = 0.0  # continuous: rad/s asked per rad of error (0: no_load_speed / SATURATION_ERROR)
    deadband: float = 0.0  # position: rad of target error; continuous: share of full command
    damping: float = 0.0  # N m s/rad: the servo's viscous friction at its output (added to the hinge's own)
    friction: float = 0.0  # N m: its Coulomb friction at the output (the hinge's frictionloss)
    armature: float = 0.0  # kg m^2: its rotor's inertia seen at the output (gear ratio squared x rotor)
    backlash: float = 0.0  # rad: the gear train's play (the motor turns this far before it drives the output)
    encoder_resolution: float = 0.0  # rad: the step of the angle the servo's loop reads (0: exact)
    voltage: float = 0.0  # V, the supply (0: the rated voltage)
    rated_voltage: float = 0.0  # V at which stall_torque and no_load_speed are given (0: not stated)


@dataclasses.dataclass(frozen=True)
class ServoParams:
    """A resolved DC-motor servo at its supply voltage. ``model`` is static (a name) when every env has the
    same one, or a traced array (1: continuous, 0: position) when each env draws a robot; the figures are
    floats or per-servo arrays read back from a model (``hsa_mjx.sim.servo.figures``)."""

    model: Any
    stall_torque: Any
    no_load_speed: Any
    kp: Any
    speed_gain: Any
    deadband: Any
    damping: Any = 0.0
    friction: Any = 0.0
    armature: Any = 0.0
    backlash: Any = 0.0
    encoder_resolution: Any = 0.0

    @property
    def back_emf(self) -> Any:
        """Torque lost per rad/s of joint speed (N m s/rad): the torque-speed line's slope."""
        return self.stall_torque / self.no_load_speed


def validate(config: ServoConfig) -> ServoConfig:
    """Raise ValueError naming the key for an unknown model, a negative number, a DC-motor servo without
    its stall torque and no-load speed, or DC-motor figures on the spring; return the config."""
    if config.model not in MODELS:
        raise ValueError(f"config key 'servo.model' = {config.model!r} is not valid; choose one of {list(MODELS)}")
    numbers = [f.name for f in dataclasses.fields(ServoConfig) if f.name != "model"]
    for key in numbers:
        if getattr(config, key) < 0:
            raise ValueError(f"config key 'servo.{key}' must be >= 0, got {getattr(config, key)!r}")
    if config.model == "spring":
        given = [key for key in numbers if getattr(config, key)]
        if given:
            raise ValueError(f"config keys {['servo.' + k for k in given]} need servo.model position or continuous")
        return config
    if config.voltage and not config.rated_voltage:
        raise ValueError("config key 'servo.voltage' needs servo.rated_voltage (the voltage the figures are given at)")
    params = resolve_servo(config)
    if params.model == "continuous" and params.deadband >= 1:
        raise ValueError(
            f"config key 'servo.deadband' of a continuous servo is a share of full command (< 1), "
            f"got {params.deadband!r}"
        )
    for key in ("stall_torque", "no_load_speed"):
        if not getattr(params, key) > 0:
            raise ValueError(f"config key 'servo.{key}' must be > 0 for a {params.model} servo (or set env.robot)")
    return config


def voltage_ratio(config: ServoConfig) -> float:
    """The supply over the rated voltage (1 when either is not given): a DC motor's stall torque and no-load
    speed both scale with it (stall current and back-EMF speed are proportional to the voltage)."""
    return config.voltage / config.rated_voltage if config.voltage and config.rated_voltage else 1.0


def resolve_servo(config: ServoConfig) -> ServoParams | None:
    """The servo's figures at its supply voltage (the loop gains defaulted), or None for the spring."""
    if config.model == "spring":
        return None
    ratio = voltage_ratio(config)
    stall, speed = config.stall_torque * ratio, config.no_load_speed * ratio
    return ServoParams(
        model=config.model,
        stall_torque=stall,
        no_load_speed=speed,
        kp=config.kp or stall / SATURATION_ERROR,
        speed_gain=config.speed_gain or speed / SATURATION_ERROR,
        deadband=config.deadband,
        damping=config.damping,
        friction=config.friction,
        armature=config.armature,
        backlash=config.backlash,
        encoder_resolution=config.encoder_resolution,
    )

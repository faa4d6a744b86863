"""``env.servo``: which servo model the robot's eight servos follow, its figures and the presets of
common servo classes (data-sheet figures, each with its source). The model itself: ``hsa_mjx.sim.servo``.
"""

from __future__ import annotations

import dataclasses
import math

MODELS = ("spring", "position", "continuous")
# Full drive at this target error (rad) unless kp or speed_gain is given: a servo's loop gain is a
# setting, not a data-sheet figure.
SATURATION_ERROR = 0.1
KGF_CM = 0.0980665  # N m
RPM = 2.0 * math.pi / 60.0  # rad/s


@dataclasses.dataclass(frozen=True)
class ServoConfig:
    """``env.servo``: the servo model. Numbers left at 0 come from the preset (or the defaults above)."""

    model: str = "spring"  # spring (the asset's), position or continuous
    preset: str = ""  # a PRESETS name: the model and every number left at 0
    stall_torque: float = 0.0  # N m
    no_load_speed: float = 0.0  # rad/s
    kp: float = 0.0  # position: N m per rad of target error (default stall_torque / SATURATION_ERROR)
    speed_gain: float = 0.0  # continuous: rad/s asked per rad of error (default no_load_speed / SATURATION_ERROR)
    deadband: float = 0.0  # position: rad of target error; continuous: share of full command


@dataclasses.dataclass(frozen=True)
class Preset:
    """A servo class's data-sheet figures and where they come from."""

    model: str
    stall_torque: float
    no_load_speed: float
    deadband: float
    source: str


# Hobby servos: a 1,000-2,000 us pulse over about 180 degrees (5.6 us a degree) turns a dead band in
# microseconds into an angle. Dynamixel servos run their own position loop (multi-turn in extended
# position mode), modelled as ``position`` servos without a dead band.
PRESETS = {
    "mg90s": Preset(
        "position", 1.8 * KGF_CM, math.pi / 3 / 0.10, math.radians(5 / 5.6),
        "MG90S data sheet: 1.8 kgf cm stall, 0.1 s/60 deg, 5 us dead band (4.8 V)",
    ),
    "mg995": Preset(
        "position", 13.0 * KGF_CM, math.pi / 3 / 0.17, math.radians(4 / 5.6),
        "Tower Pro MG995: 13 kgf cm stall, 0.17 s/60 deg, 4 us dead band (4.8 V)",
    ),
    "dfr05sr": Preset(
        "continuous", 4.8 * KGF_CM, 60 * RPM, 0.0,
        "DFRobot DF05SR 360-degree servo (SER0017): 4.8 kgf cm, 60 rpm average (4.8 V)",
    ),
    "xl330_m288": Preset(
        "position", 0.52, 103 * RPM, 0.0,
        "ROBOTIS e-manual, XL330-M288-T: 0.52 N m stall, 103 rpm no load (5.0 V)",
    ),
    "2xl430_w250": Preset(
        "position", 1.4, 57 * RPM, 0.0,
        "ROBOTIS e-manual, 2XL430-W250: 1.4 N m stall, 57 rpm no load (11.1 V)",
    ),
    "mx28": Preset(
        "position", 2.5, 55 * RPM, 0.0,
        "ROBOTIS e-manual, MX-28 (protocol 2.0): 2.5 N m stall, 55 rpm no load (12 V)",
    ),
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class ServoParams:
    """A resolved DC-motor servo (static: shapes and branches depend on ``model`` only)."""

    model: str
    stall_torque: float
    no_load_speed: float
    kp: float
    speed_gain: float
    deadband: float

    @property
    def back_emf(self) -> float:
        """Torque lost per rad/s of joint speed (N m s/rad): the torque-speed line's slope."""
        return self.stall_torque / self.no_load_speed


def validate(config: ServoConfig) -> ServoConfig:
    """Raise ValueError naming the key for an unknown model or preset, a negative number, or a DC-motor
    servo without its stall torque and no-load speed; return the config."""
    if config.model not in MODELS:
        raise ValueError(f"config key 'servo.model' = {config.model!r} is not valid; choose one of {list(MODELS)}")
    if config.preset and config.preset not in PRESETS:
        raise ValueError(f"config key 'servo.preset' = {config.preset!r} is not valid; choose one of {sorted(PRESETS)}")
    numbers = ("stall_torque", "no_load_speed", "kp", "speed_gain", "deadband")
    for key in numbers:
        if getattr(config, key) < 0:
            raise ValueError(f"config key 'servo.{key}' must be >= 0 (0: the preset's), got {getattr(config, key)!r}")
    if config.model == "spring" and not config.preset:
        given = [key for key in numbers if getattr(config, key)]
        if given:
            raise ValueError(f"config keys {['servo.' + k for k in given]} need servo.model position or continuous")
        return config
    params = resolve_servo(config)
    if params.model == "continuous" and params.deadband >= 1:
        raise ValueError(
            f"config key 'servo.deadband' of a continuous servo is a share of full command (< 1), "
            f"got {params.deadband!r}"
        )
    for key in ("stall_torque", "no_load_speed"):
        if not getattr(params, key) > 0:
            raise ValueError(f"config key 'servo.{key}' must be > 0 for a {params.model} servo (or give servo.preset)")
    return config


def check_presets(config: ServoConfig, names: tuple[str, ...]) -> None:
    """ValueError unless ``config`` names its nominal class (``servo.preset``), every name is a preset of
    that DC-motor servo model and the config leaves the figures the presets give (stall torque,
    no-load speed, deadband) at 0 (``randomization.servo_presets``)."""
    if not names:
        return
    params = resolve_servo(config)
    if params is None or not config.preset:
        raise ValueError(
            "config key 'randomization.servo_presets' draws DC-motor servos: set servo.preset, the nominal "
            "class the model is built with (a preset of the same model as the drawn ones)"
        )
    for name in names:
        if name not in PRESETS:
            raise ValueError(
                f"config key 'randomization.servo_presets' has {name!r}, not a preset; choose from {sorted(PRESETS)}"
            )
        if PRESETS[name].model != params.model:
            same = sorted(n for n, p in PRESETS.items() if p.model == params.model)
            raise ValueError(
                f"config key 'randomization.servo_presets': {name!r} is a {PRESETS[name].model} servo and "
                f"servo.model is {params.model}; presets of that model: {same}"
            )
    given = [f"servo.{key}" for key in ("stall_torque", "no_load_speed", "deadband") if getattr(config, key)]
    if given:
        raise ValueError(f"config keys {given} are set by each drawn preset: leave them at 0 with servo_presets")


def preset_servos(config: ServoConfig, names: tuple[str, ...]) -> list[ServoParams]:
    """Each named preset resolved as ``config``'s servo (its model; its ``kp`` and ``speed_gain`` where given)."""
    return [resolve_servo(dataclasses.replace(config, preset=name)) for name in names]


def resolve_servo(config: ServoConfig) -> ServoParams | None:
    """The servo's figures (a preset's where the config leaves them at 0), or None for the spring."""
    preset = PRESETS.get(config.preset)
    model = preset.model if preset and config.model == "spring" else config.model
    if model == "spring":
        return None
    stall = config.stall_torque or (preset.stall_torque if preset else 0.0)
    speed = config.no_load_speed or (preset.no_load_speed if preset else 0.0)
    deadband = config.deadband or (preset.deadband if preset else 0.0)
    return ServoParams(
        model=model,
        stall_torque=stall,
        no_load_speed=speed,
        kp=config.kp or stall / SATURATION_ERROR,
        speed_gain=config.speed_gain or speed / SATURATION_ERROR,
        deadband=deadband,
    )

"""The robustness benchmark's grids: the cells a policy is scored on and what each cell changes.

A cell is a dict of every factor in ``FACTORS`` (the training model's value where the cell leaves one
alone), so both grids run through one code path:

- ``nominal``: floor friction x0.5 / x1 / x1.5, block masses x0.8 / x1.2, HSA stiffness x0.7 / x1.3,
  latency 0 / 20 / 40 ms, observation noise off / on (``NOISE``): 72 cells, all within the span
  that ``configs/train_flat_dr.yaml`` trains on;
- ``stress``: the training model, each factor alone at both ends of its stress range (friction x0.3
  and x2, masses x0.6 and x1.4, HSA stiffness and damping x0.5 and x1.5, servo gain x0.6 and x1.2,
  a servo torque limit, 60 ms latency, pushes, observation noise, one slick foot, feet without
  their anisotropy, the servos of the three hardware robot profiles (``hsa_mjx.robots``) in place of the
  policy's own), and four corners where they combine: 24 cells. ``docs/robustness.md`` justifies each
  range from what varies on a real robot.

A policy that drives DC-motor servos (a hardware profile's) is scored on the same cells, the servo gain
and torque limit read as its motors' figures (:func:`dc_motor_cell`).
"""

from __future__ import annotations

import itertools
from typing import Any

from hsa_mjx.deploy.perturbation import ONES, ModelPerturbation, per_foot
from hsa_mjx.randomization_config import FOOT_KEYS, SCALE_KEYS
from hsa_mjx.robots import profile_names, profile_servo

SCALES = SCALE_KEYS  # the physical scales, as the env's randomisation names them
MODEL = (*SCALES, "servo_torque_limit", *FOOT_KEYS)  # the factors a ModelPerturbation carries
FACTORS = (*SCALES, "servo_torque_limit", *FOOT_KEYS, "servo", "latency_ms", "pushes", "noise")
TRAINING = {
    **dict.fromkeys(SCALES, 1.0),
    "servo_torque_limit": None,
    **dict.fromkeys(FOOT_KEYS, ONES),  # four scales each, one per foot (hsa_mjx.sim.model.FOOT_PAIRS' order)
    "servo": None,  # a robot profile's name: the robot's servos are that profile's (None: the policy's own)
    "latency_ms": 0,
    "pushes": False,
    "noise": False,
}
MAX_LATENCY_MS = 200
# observation noise of a cell with noise on: uniform +-value (about 1 degree on the hinge encoders,
# 1 cm on the position tracker; configs/train_flat_dr.yaml trains with the same)
NOISE = {
    "hinge_angles": 0.02,
    "hinge_velocities": 0.2,
    "position": 0.01,
    "velocity": 0.02,
    "goal": 0.01,
    "heading": 0.02,
}
# pushes of a cell with pushes on: every 2-4 s, a horizontal velocity of up to 0.3 m/s added to both
# blocks (about four times the robot's crawling speed)
PUSH_INTERVAL_S = (2.0, 4.0)
PUSH_SPEED = 0.3
# the stress grid's servo torque limit (N m): a small smart servo's stall torque, below the median
# torque the flat policy's gait asks for (docs/robustness.md)
STRESS_TORQUE_LIMIT = 0.5
# one foot (cylinder 3a's) on a slick patch, the others as trained
SLICK_FOOT = (0.3, 1.0, 1.0, 1.0)
# every foot's lower sliding coefficient raised to its higher one (0.1 -> 0.21): feet that grip the same
# along and across the robot (worn or other pads), the anisotropy the crawl relies on gone
ISOTROPIC_FEET = (2.1,) * 4
# servos in place of the policy's: the hardware profiles' (a continuous-rotation hobby servo, the class the
# robot is built with; a Dynamixel position servo; a strong hobby position servo)
STRESS_SERVOS = ("dfr05sr", "xl330_m288", "st3215")


def cell(**changes: Any) -> dict[str, Any]:
    """The training model with ``changes``, checked (ValueError naming the factor and its range)."""
    unknown = set(changes) - set(FACTORS)
    if unknown:
        raise ValueError(f"unknown factors {sorted(unknown)}; factors: {', '.join(FACTORS)}")
    out = {**TRAINING, **changes}
    for name in FOOT_KEYS:
        out[name] = tuple(out[name]) if isinstance(out[name], list | tuple) else out[name]
    check(out)
    return out


def check(c: dict[str, Any]) -> None:
    """ValueError unless every factor of cell ``c`` is in its valid range."""
    ModelPerturbation(**{name: c[name] for name in MODEL})  # the scales, the limit and the feet
    if c["servo"] is not None:
        hardware = [name for name in profile_names() if profile_servo(name).model != "spring"]
        if c["servo"] not in hardware:
            raise ValueError(
                f"servo must be None or a robot profile with DC-motor servos, got {c['servo']!r}: {hardware}"
            )
        if c["servo_gain"] != 1.0 or c["servo_torque_limit"] is not None:
            raise ValueError(
                "servo_gain and servo_torque_limit act on the asset's springs: not with a profile's servos"
            )
    if not (isinstance(c["latency_ms"], int | float) and 0 <= c["latency_ms"] <= MAX_LATENCY_MS):
        raise ValueError(f"latency_ms must be in [0, {MAX_LATENCY_MS}], got {c['latency_ms']!r}")
    for name in ("pushes", "noise"):
        if not isinstance(c[name], bool):
            raise ValueError(f"{name} must be true or false, got {c[name]!r}")


def dc_motor_cell(c: dict[str, Any], stall_torque: float) -> tuple[dict[str, Any], tuple[float, ...]]:
    """Cell ``c`` for a policy whose own servos are DC motors of ``stall_torque`` N m: the gain and torque
    limit, which act on the asset's springs, become the motor's figures: ``servo_gain`` scales the stall
    torque and no-load speed together (the supply voltage off its rating), a torque limit caps the stall
    torque. Returns the cell without them and the five ``servo_figures`` scales
    (``hsa_mjx.task.randomization.SERVO_FIGURES``' order: stall torque, no-load speed, damping, friction,
    rotor inertia)."""
    gain, limit = c["servo_gain"], c["servo_torque_limit"]
    stall = gain * stall_torque if limit is None else min(gain * stall_torque, limit)
    return {**c, "servo_gain": 1.0, "servo_torque_limit": None}, (stall / stall_torque, gain, 1.0, 1.0, 1.0)


def nominal_grid() -> list[dict[str, Any]]:
    """The 72 cells within the randomised training span."""
    values = {
        "friction": (0.5, 1.0, 1.5),
        "block_mass": (0.8, 1.2),
        "hsa_stiffness": (0.7, 1.3),
        "latency_ms": (0, 20, 40),
        "noise": (False, True),
    }
    return [cell(**dict(zip(values, combo))) for combo in itertools.product(*values.values())]


STRESS_ENDS = {
    "friction": (0.3, 2.0),
    "block_mass": (0.6, 1.4),
    "hsa_stiffness": (0.5, 1.5),
    "hsa_damping": (0.5, 1.5),
    "servo_gain": (0.6, 1.2),
}


def stress_grid() -> list[dict[str, Any]]:
    """The training model, each factor alone at each end of its stress range, and four corners."""
    alone = [cell(**{name: value}) for name, ends in STRESS_ENDS.items() for value in ends]
    alone += [
        cell(servo_torque_limit=STRESS_TORQUE_LIMIT),
        cell(latency_ms=60),
        cell(pushes=True),
        cell(noise=True),
        cell(foot_friction=SLICK_FOOT),
        cell(foot_anisotropy=ISOTROPIC_FEET),
        *(cell(servo=name) for name in STRESS_SERVOS),
    ]
    corners = [
        # a slick floor under a stiff, heavy robot with weak, late servos
        cell(friction=0.3, block_mass=1.4, hsa_stiffness=1.5, servo_gain=0.6, latency_ms=60),
        # a grippy floor under a light, soft robot with strong servos, pushed and sensed noisily
        cell(friction=2.0, block_mass=0.6, hsa_stiffness=0.5, hsa_damping=0.5, servo_gain=1.2, pushes=True, noise=True),
        # torque-limited and late on a slick floor, with pushes
        cell(friction=0.3, servo_torque_limit=STRESS_TORQUE_LIMIT, latency_ms=60, pushes=True),
        # every factor at its harder end at once
        cell(
            friction=0.3,
            block_mass=1.4,
            hsa_stiffness=1.5,
            hsa_damping=1.5,
            servo_gain=0.6,
            servo_torque_limit=STRESS_TORQUE_LIMIT,
            latency_ms=60,
            pushes=True,
            noise=True,
        ),
    ]
    return [cell(), *alone, *corners]


GRIDS = {"nominal": nominal_grid, "stress": stress_grid}


def rollout_groups(cells: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """The cells in groups that share one compiled env: the same noise setting, and the policy's own servos
    or a profile's (each env then drives its cell's profile's servo, of either DC-motor model)."""
    keys = list(dict.fromkeys((c["noise"], c["servo"] is None) for c in cells))
    return [[c for c in cells if (c["noise"], c["servo"] is None) == key] for key in keys]


def grid(name: str) -> list[dict[str, Any]]:
    """The cells of grid ``name`` (ValueError naming the grids)."""
    if name not in GRIDS:
        raise ValueError(f"unknown grid {name!r}; grids: {', '.join(GRIDS)}")
    return GRIDS[name]()


def label(c: dict[str, Any]) -> str:
    """A short name of what cell ``c`` changes ("training model" when nothing)."""
    parts = [f"{name} x{c[name]:g}" for name in SCALES if c[name] != 1.0]
    if c["servo_torque_limit"] is not None:
        parts.append(f"torque <= {c['servo_torque_limit']:g} N m")
    parts += [f"{name} x{per_foot(c[name])}" for name in FOOT_KEYS if c[name] != ONES]
    parts += [f"servo {c['servo']}"] if c["servo"] is not None else []
    if c["latency_ms"]:
        parts.append(f"{c['latency_ms']:g} ms")
    parts += [name for name in ("pushes", "noise") if c[name]]
    return ", ".join(parts) or "training model"


def _parse(name: str, text: str) -> Any:
    """A ``--where`` value of factor ``name`` in the cells' type."""
    text = text.strip().lower()
    if name in ("pushes", "noise"):
        flags = {"on": True, "true": True, "off": False, "false": False}
        if text not in flags:
            raise ValueError(f"{name} takes on or off, got {text!r}")
        return flags[text]
    if name in ("servo_torque_limit", "servo") and text in ("none", "off"):
        return None
    if name == "servo":
        return text
    try:
        if name in FOOT_KEYS:  # four values, e.g. 0.3/1/1/1
            return tuple(float(v) for v in text.split("/"))
        return float(text)
    except ValueError as err:
        what = "four numbers a/b/c/d (one per foot)" if name in FOOT_KEYS else "a number"
        raise ValueError(f"{name} takes {what}, got {text!r}") from err


def select(cells: list[dict[str, Any]], where: list[str]) -> list[dict[str, Any]]:
    """The cells matching every factor of ``FACTOR=VALUE`` items, any of the values where a factor is given
    more than once (ValueError naming the factors, or the values there are)."""
    wanted: dict[str, list[Any]] = {}
    for item in where:
        name, _, text = item.partition("=")
        if name not in FACTORS:
            raise ValueError(f"--where {item!r}: unknown factor {name!r}; factors: {', '.join(FACTORS)}")
        value = _parse(name, text)
        if not any(c[name] == value for c in cells):
            there = sorted({str(c[name]) for c in cells})
            raise ValueError(f"--where {item!r}: no cell has {name} = {text}; values here: {', '.join(there)}")
        wanted.setdefault(name, []).append(value)
    return [c for c in cells if all(c[name] in values for name, values in wanted.items())]


def part(cells: list[dict[str, Any]], spec: str | None) -> list[dict[str, Any]]:
    """Share ``K/N`` of ``cells`` (every N-th from the K-th, so the shares are alike; all for None)."""
    if spec is None:
        return cells
    k, _, n = spec.partition("/")
    if not (k.isdigit() and n.isdigit() and 1 <= int(k) <= int(n)):
        raise ValueError(f"--part takes K/N with 1 <= K <= N, got {spec!r}")
    chosen = cells[int(k) - 1 :: int(n)]
    if not chosen:
        raise ValueError(f"--part {spec}: no cell left of the {len(cells)} chosen")
    return chosen

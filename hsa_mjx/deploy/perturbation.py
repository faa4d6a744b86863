"""A simulated robot unlike the training model: scaled friction (of every contact, or of each foot and its
anisotropy), masses, springs and servos, a torque limit.

:class:`ModelPerturbation` names one such robot; :func:`perturbed_model` writes it into a copy of the
C MuJoCo model through the env's own randomisation (``hsa_mjx.task.randomization.model_fields``), so
that a perturbation here and the same values drawn by a training env change the same fields by the
same amounts. ``LIMITS`` bounds every value to what the model is meant to cover (``docs/robustness.md``
says why); anything outside is refused with a ``ValueError`` naming the factor and its range.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import jax
import mujoco
import numpy as np

from hsa_mjx.randomization_config import FOOT_KEYS, NO_LIMIT, NOMINAL, SCALE_KEYS, RandomizationConfig
from hsa_mjx.sim.model import RobotIndex
from hsa_mjx.task.randomization import SERVO_FIGURES, NominalModel, PhysicsScales, model_fields

# (min, max) of each factor: scales of the asset's values, the torque limit in N m
LIMITS = {
    "friction": (0.1, 3.0),
    "block_mass": (0.5, 2.0),
    "hsa_stiffness": (0.25, 2.0),
    "hsa_damping": (0.25, 2.0),
    "servo_gain": (0.25, 2.0),
    "servo_torque_limit": (0.05, 5.0),
    "foot_friction": (0.1, 3.0),  # each foot's, as four values
    "foot_anisotropy": (0.1, 3.0),  # x2.1 makes a foot's floor contact isotropic (0.1 -> 0.21)
}
FEET = 4
ONES = (1.0,) * FEET


@dataclasses.dataclass(frozen=True)
class ModelPerturbation:
    """Scales of the asset's values (1: as trained) and an optional servo torque limit (N m; None: the
    asset's, unlimited); each foot's friction and anisotropy as four values, in the order of
    ``hsa_mjx.sim.model.FOOT_PAIRS``. ValueError when a value is outside ``LIMITS``."""

    friction: float = 1.0  # every contact's sliding friction
    block_mass: float = 1.0  # both blocks' masses and inertias
    hsa_stiffness: float = 1.0  # the HSA tendon springs' stiffness
    hsa_damping: float = 1.0  # their damping
    servo_gain: float = 1.0  # the position servos' kp
    servo_torque_limit: float | None = None
    foot_friction: tuple[float, ...] = ONES  # both sliding coefficients of each foot's floor contact
    foot_anisotropy: tuple[float, ...] = ONES  # each foot's lower sliding coefficient alone

    def __post_init__(self):
        for name in FOOT_KEYS:
            value = getattr(self, name)
            if not isinstance(value, list | tuple) or len(value) != FEET:
                raise ValueError(f"{name} takes {FEET} values (one per foot), got {value!r}")
            object.__setattr__(self, name, tuple(value))
        for name, (lo, hi) in LIMITS.items():
            value = getattr(self, name)
            if value is None and name == "servo_torque_limit":
                continue
            for v in value if name in FOOT_KEYS else (value,):
                if not isinstance(v, int | float) or not lo <= v <= hi:
                    raise ValueError(f"{name} must be in [{lo:g}, {hi:g}], got {value!r}")

    @property
    def nominal(self) -> bool:
        """Whether this is the training model itself."""
        return self == ModelPerturbation()

    def randomization(self) -> RandomizationConfig:
        """The randomisation config of these values: each range [v, v]; a foot factor's range spans its four
        values (exactly them where the feet agree), so that the env writes the fields they change."""
        limit = NO_LIMIT if self.servo_torque_limit is None else (self.servo_torque_limit,) * 2
        scales = {name: (float(getattr(self, name)),) * 2 for name in SCALE_KEYS}
        feet = {name: NOMINAL if getattr(self, name) == ONES else _span(getattr(self, name)) for name in FOOT_KEYS}
        return RandomizationConfig(**scales, **feet, servo_force_limit=limit)

    def scales(self) -> PhysicsScales:
        """These values as one env's physical scales."""
        limit = math.inf if self.servo_torque_limit is None else self.servo_torque_limit
        return PhysicsScales(
            friction=np.float32(self.friction),
            block_mass=np.full(2, self.block_mass, np.float32),
            hsa_stiffness=np.float32(self.hsa_stiffness),
            hsa_damping=np.float32(self.hsa_damping),
            servo_gain=np.float32(self.servo_gain),
            servo_force_limit=np.float32(limit),
            foot_friction=np.asarray(self.foot_friction, np.float32),
            foot_anisotropy=np.asarray(self.foot_anisotropy, np.float32),
            robot=np.zeros((), np.int32),
            servo_figures=np.ones(len(SERVO_FIGURES), np.float32),
        )


def per_foot(values: tuple[float, ...]) -> str:
    """A foot factor's four values as text, e.g. ``0.3/1/1/1`` (how the grid's ``--where`` reads them)."""
    return "/".join(f"{v:g}" for v in values)


def _span(values: tuple[float, ...]) -> tuple[float, float]:
    """(min, max) of a foot factor's four values."""
    return float(min(values)), float(max(values))


def perturbed_fields(mj_model: mujoco.MjModel, index: RobotIndex, perturbation: ModelPerturbation) -> dict:
    """The model fields ``perturbation`` changes, as numpy arrays (the env's ``model_fields``). A servo
    gain or torque limit on DC-motor servos (``env.servo``) is a ValueError: both act on the springs."""
    if len(index.drive_ids) and (perturbation.servo_gain != 1.0 or perturbation.servo_torque_limit is not None):
        raise ValueError(
            "servo_gain and servo_torque_limit act on the asset's spring servos; this model's servos are DC "
            "motors (env.servo): change their stall torque in the policy's env.servo instead"
        )
    fields = model_fields(NominalModel.from_model(mj_model, index), perturbation.scales(), perturbation.randomization())
    return {name: np.asarray(jax.device_get(value), np.float64) for name, value in fields.items()}


def perturbed_model(mj_model: mujoco.MjModel, index: RobotIndex, perturbation: ModelPerturbation) -> mujoco.MjModel:
    """A copy of ``mj_model`` with the perturbation written into it (the original is left as it is)."""
    model = copy.copy(mj_model)
    for name, value in perturbed_fields(mj_model, index, perturbation).items():
        np.copyto(getattr(model, name), value)
    if perturbation.servo_torque_limit is not None:
        model.actuator_forcelimited[np.asarray(index.servo_ids)] = 1
    return model

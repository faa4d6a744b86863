"""One env on a CPU: the physics substeps in C MuJoCo, everything else the env's own jitted code.

MJX's JAX implementation is built for thousands of envs at once; one env on a CPU pays XLA's
per-op cost on every substep, and C MuJoCo steps the same compiled model several times faster
(``python -m benchmarks.speed.single_env``; docs/speed.md). :class:`HostPhysics` runs the ``frame_skip`` substeps of
``HSAEnv.step_with`` on a C ``MjData``, through ``jax.pure_callback`` inside a jitted step (a batch), or
:meth:`HostPhysics.run` called between the step's two jitted halves (the Gymnasium env, no callback: its
``HostStep``). The state goes in through
public ``mjx.Data`` fields (``qpos``, ``qvel``, ``act``, ``ctrl``, ``mocap_*``, the solver warm start,
``time``) and comes back through the fields the env reads (positions, orientations, ``qacc``,
``sensordata``), so the control law, observation, reward and termination are exactly the env's.

It differs from MJX only in arithmetic: float64 C MuJoCo with its own solver (the same settings)
against float32 MJX; ``tests/test_host_physics.py`` bounds the difference over a gait. C MuJoCo
resets a diverging state by itself; such a substep is reported as non-finite, as MJX's NaN would
be. ``physics.backend: c`` steps an env with it; the Gymnasium single env and evaluation do so by default on a CPU.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.servo_config import ServoParams
from hsa_mjx.sim import servo
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import RobotIndex
from hsa_mjx.sim.physics import SubstepStats

STATE_IN = ("qpos", "qvel", "act", "ctrl", "mocap_pos", "mocap_quat", "qacc_warmstart", "time")
STATE_OUT = (
    "qpos",
    "qvel",
    "act",
    "ctrl",
    "qacc",
    "qacc_warmstart",
    "time",
    "xpos",
    "xquat",
    "sensordata",
    "actuator_force",
)
_BAD = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQACC)


class HostPhysics:
    """C MuJoCo substeps for ``HSAEnv.step_with`` (one env; under ``vmap`` envs run one after another).

    Args:
        mj_model: the env's compiled C model (``env.robot.mj_model``: same asset, physics and terrain).
        index: the env's name index (servo ids).
        motors: the DC-motor servos' figures (None: the asset's springs): each substep's drive is
            computed here as ``hsa_mjx.sim.physics.simulate`` does on the device.
    """

    def __init__(self, mj_model: mujoco.MjModel, index: RobotIndex, motors: ServoParams | None = None):
        # its own copy: per-env model fields are written into it before each env's substeps
        self.model, self.index, self.motors = copy.copy(mj_model), index, motors
        self.data = mujoco.MjData(self.model)

    def __call__(
        self,
        data: mjx.Data,
        targets: jax.Array,
        fields: dict[str, jax.Array] | None = None,
        idle: jax.Array | None = None,
    ) -> tuple[mjx.Data, SubstepStats]:
        """Run one substep per row of ``targets`` (frame_skip, 8) from ``data``; the new data and stats.

        ``fields``: model fields of this env (``hsa_mjx.task.randomization.model_fields``), written into
        the C model before its substeps. ``idle`` (a bool scalar, traced): True runs no substep and
        returns a state to be discarded, for an episode that has ended while others play on
        (``train.episodes.rollout``): a batch of C MuJoCo episodes then costs the steps they play, not the
        longest one's."""
        fields = fields or {}
        idle = jnp.zeros((), bool) if idle is None else jnp.asarray(idle, bool)
        names, shapes = tuple(fields), self.output_shapes(data)
        out = jax.pure_callback(
            lambda i, *a: self.run(bool(i), names, shapes, *a),
            shapes,
            idle,
            *self.inputs(data, targets, fields),
            vmap_method="sequential",
        )
        return self.outputs(data, out)

    @staticmethod
    def inputs(data: mjx.Data, targets: jax.Array, fields: dict[str, jax.Array]) -> tuple[jax.Array, ...]:
        """What the substeps read (traceable): the state fields ``STATE_IN``, the targets, the model fields."""
        return tuple(getattr(data, name) for name in STATE_IN) + (targets,) + tuple(fields.values())

    @staticmethod
    def output_shapes(data: mjx.Data) -> tuple[jax.ShapeDtypeStruct, ...]:
        """Shapes and dtypes of what :meth:`run` returns: the fields ``STATE_OUT`` of ``data``, then the stats."""
        fields = tuple(jax.ShapeDtypeStruct(getattr(data, n).shape, getattr(data, n).dtype) for n in STATE_OUT)
        return fields + (jax.ShapeDtypeStruct((4,), jnp.float32),)

    @staticmethod
    def outputs(data: mjx.Data, out: tuple[jax.Array, ...]) -> tuple[mjx.Data, SubstepStats]:
        """The new data and stats from what :meth:`run` returned (traceable)."""
        *fields, stats = out
        new = data.replace(**dict(zip(STATE_OUT, fields)))
        return new, SubstepStats(
            max_abs_qvel=stats[0], max_abs_qacc=stats[1], non_finite=stats[2] > 0, final_abs_qacc=stats[3]
        )

    def run(self, idle: bool, names: tuple[str, ...], shapes: tuple, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
        """Host side: load the model fields ``names`` and the state (:meth:`inputs`), step (unless idle),
        return the fields ``STATE_OUT`` and the stats in ``shapes`` (:meth:`output_shapes`)."""
        state, targets, values = arrays[: len(STATE_IN)], arrays[len(STATE_IN)], arrays[len(STATE_IN) + 1 :]
        for name, value in zip(names, values):
            np.copyto(getattr(self.model, name), np.asarray(value, np.float64))
        d = self.data
        for name, value in zip(STATE_IN, state):
            if name == "time":
                d.time = float(value)
            else:
                np.copyto(getattr(d, name), np.asarray(value, np.float64).reshape(getattr(d, name).shape))
        counts = [d.warning[w].number for w in _BAD]
        targets = np.asarray(targets, np.float64)[: 0 if idle else len(targets)]
        qvel, qacc = np.zeros((max(len(targets), 1), self.model.nv)), np.zeros((max(len(targets), 1), self.model.nv))
        for i, target in enumerate(targets):
            servo.write_controls(self.model, d, self.index, self.motors, target)
            mujoco.mj_step(self.model, d)
            qvel[i], qacc[i] = d.qvel, d.qacc
        qvel, qacc = np.abs(qvel).max(axis=1), np.abs(qacc).max(axis=1)  # per substep; a NaN stays a NaN
        reset = any(d.warning[w].number > c for w, c in zip(_BAD, counts))  # C MuJoCo reset a bad state
        bad = reset or not (np.isfinite(qvel).all() and np.isfinite(qacc).all() and np.isfinite(d.qpos).all())
        if bad:  # finite stats for the termination rules (the state is discarded)
            qvel, qacc = np.nan_to_num(qvel), np.nan_to_num(qacc)
        stats = np.array([qvel.max(), qacc.max(), float(bad), qacc[-1]], np.float32)
        outs = tuple(np.asarray(getattr(d, n), s.dtype).reshape(s.shape) for n, s in zip(STATE_OUT, shapes))
        return outs + (stats,)

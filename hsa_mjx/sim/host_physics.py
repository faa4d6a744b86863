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
Both directions travel as one float32 vector laid out as C MuJoCo's own state vector
(``mj_setState`` / ``mj_getState``: one C call each way) followed by the targets, the model fields and,
coming back, the other fields and the substeps' stats: one array each way costs a few microseconds
where one per field cost about 60 per env step.

It differs from MJX only in arithmetic: float64 C MuJoCo with its own solver (the same settings)
against float32 MJX; ``tests/test_host_physics.py`` bounds the difference over a gait. C MuJoCo
resets a diverging state by itself; such a substep is reported as non-finite, as MJX's NaN would
be. ``physics.backend: c`` steps an env with it; the Gymnasium single env and evaluation do so by default on a CPU.
"""

from __future__ import annotations

import copy
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.servo_config import ServoParams
from hsa_mjx.sim import servo
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import RobotIndex
from hsa_mjx.sim.physics import SubstepStats

STATE_IN = ("time", "qpos", "qvel", "act", "qacc_warmstart", "ctrl", "mocap_pos", "mocap_quat")
STATE_OUT = ("time", "qpos", "qvel", "act", "qacc_warmstart", "ctrl")
EXTRA_OUT = ("qacc", "xpos", "xquat", "sensordata", "actuator_force")
STATS = 4  # max |qvel| and max |qacc| over the substeps, non-finite, |qacc| after the last substep
# the flag of each field in C MuJoCo's state vector; fields lie in the order of these flags
_FLAG = {
    "time": mujoco.mjtState.mjSTATE_TIME,
    "qpos": mujoco.mjtState.mjSTATE_QPOS,
    "qvel": mujoco.mjtState.mjSTATE_QVEL,
    "act": mujoco.mjtState.mjSTATE_ACT,
    "qacc_warmstart": mujoco.mjtState.mjSTATE_WARMSTART,
    "ctrl": mujoco.mjtState.mjSTATE_CTRL,
    "mocap_pos": mujoco.mjtState.mjSTATE_MOCAP_POS,
    "mocap_quat": mujoco.mjtState.mjSTATE_MOCAP_QUAT,
}
# C MuJoCo's warnings of a state it reset (their counts in ``MjData.warning.number``)
_BAD = [
    int(w)
    for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQACC)
]


class Layout(NamedTuple):
    """What follows the state in the input vector (static): the servo targets of shape ``targets``
    (substeps, servos), then the model fields ``fields`` as (name, shape) pairs."""

    targets: tuple[int, int]
    fields: tuple[tuple[str, tuple[int, ...]], ...]


def state_spec(names: tuple[str, ...]) -> int:
    """The ``mjtState`` bits of these fields (their order in the vector is the bits' order)."""
    flags = [int(_FLAG[n]) for n in names]
    if flags != sorted(flags):
        raise ValueError(f"fields {names} are not in C MuJoCo's state order")
    return sum(flags)


def _flat(array: jax.Array) -> jax.Array:
    return jnp.ravel(array).astype(jnp.float32)


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
        self._spec_in, self._spec_out = state_spec(STATE_IN), state_spec(STATE_OUT)
        self._size_in = mujoco.mj_stateSize(self.model, self._spec_in)
        self._size_out = mujoco.mj_stateSize(self.model, self._spec_out)
        extra = [getattr(self.data, n).size for n in EXTRA_OUT]
        self._extra = tuple(zip(EXTRA_OUT, np.cumsum([self._size_out] + extra[:-1]).tolist(), extra))
        self._out = np.zeros(self._size_out + sum(extra) + STATS)  # reused: run returns a float32 copy

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
        layout = self.layout(targets, fields)
        out = jax.pure_callback(
            lambda i, vector: self.run(bool(i), layout, vector),
            self.output_shape(),
            idle,
            self.inputs(data, targets, fields),
            vmap_method="sequential",
        )
        return self.outputs(data, out)

    @staticmethod
    def layout(targets: Any, fields: dict[str, Any]) -> Layout:
        """The static layout of :meth:`inputs` beyond the state, from shapes alone (arrays, tracers or
        ``jax.ShapeDtypeStruct``). The fields lie in the order of their names, as in :meth:`inputs`: a dict
        that went through a pytree (``jax.eval_shape``, ``jit``) comes back with its keys sorted."""
        return Layout(tuple(targets.shape), tuple((name, tuple(fields[name].shape)) for name in sorted(fields)))

    @staticmethod
    def inputs(data: mjx.Data, targets: jax.Array, fields: dict[str, jax.Array]) -> jax.Array:
        """What the substeps read as one float32 vector (traceable): the state fields ``STATE_IN`` in C
        MuJoCo's state order, the targets, the model fields in the order of their names (:meth:`layout`)."""
        parts = [getattr(data, name) for name in STATE_IN] + [targets] + [fields[name] for name in sorted(fields)]
        return jnp.concatenate([_flat(part) for part in parts])

    def output_shape(self) -> jax.ShapeDtypeStruct:
        """The shape and dtype of what :meth:`run` returns."""
        return jax.ShapeDtypeStruct(self._out.shape, jnp.float32)

    @staticmethod
    def outputs(data: mjx.Data, out: jax.Array) -> tuple[mjx.Data, SubstepStats]:
        """The new data and stats from what :meth:`run` returned (traceable): the fields ``STATE_OUT``
        and ``EXTRA_OUT`` of ``data`` in that order, then the stats."""
        new, offset = {}, 0
        for name in STATE_OUT + EXTRA_OUT:
            like = getattr(data, name)
            new[name] = out[offset : offset + like.size].reshape(like.shape).astype(like.dtype)
            offset += like.size
        stats = out[offset : offset + STATS]
        return data.replace(**new), SubstepStats(
            max_abs_qvel=stats[0], max_abs_qacc=stats[1], non_finite=stats[2] > 0, final_abs_qacc=stats[3]
        )

    def run(self, idle: bool, layout: Layout, vector: np.ndarray) -> np.ndarray:
        """Host side: load the state, targets and model fields of ``vector`` (:meth:`inputs`), step
        once per row of targets (none when ``idle``), return the float32 vector :meth:`outputs` reads."""
        m, d = self.model, self.data
        vector = np.asarray(vector, np.float64)
        mujoco.mj_setState(m, d, vector[: self._size_in], self._spec_in)
        offset = self._size_in + math.prod(layout.targets)
        targets = vector[self._size_in : offset].reshape(layout.targets)
        for name, shape in layout.fields:
            size = math.prod(shape)
            np.copyto(getattr(m, name), vector[offset : offset + size].reshape(shape))
            offset += size
        warnings = d.warning.number[_BAD].copy()
        steps = 0 if idle else layout.targets[0]
        rows = np.zeros((max(steps, 1), 2, m.nv))  # each substep's qvel and qacc
        qvel, qacc = d.qvel, d.qacc  # views of the C arrays, fetched once
        for row, target in zip(rows, targets[:steps]):
            servo.write_controls(m, d, self.index, self.motors, target)
            mujoco.mj_step(m, d)
            row[0], row[1] = qvel, qacc
        return self._collect(d, rows, bool((d.warning.number[_BAD] > warnings).any()))

    def _collect(self, d: mujoco.MjData, rows: np.ndarray, reset: bool) -> np.ndarray:
        """The output vector: the state, the other fields, the stats of the substeps' ``rows`` of qvel and
        qacc (``reset``: C MuJoCo reset a bad state during them)."""
        out = self._out
        mujoco.mj_getState(self.model, d, out[: self._size_out], self._spec_out)
        for name, offset, size in self._extra:
            out[offset : offset + size] = getattr(d, name).ravel()
        peaks = np.abs(rows).max(axis=2)  # (substeps, 2); a NaN stays a NaN
        bad = reset or not (np.isfinite(peaks).all() and np.isfinite(d.qpos).all())
        if bad:  # finite stats for the termination rules (the state is discarded)
            peaks = np.nan_to_num(peaks)
        out[-STATS:] = peaks[:, 0].max(), peaks[:, 1].max(), float(bad), peaks[-1, 1]
        return out.astype(np.float32)

"""Fidelity guard: do the fast physics settings still move the robot like the original's physics?

Open-loop gaits (``benchmarks/fidelity/gaits.py``) are played on flat ground for ``--duration`` seconds
(default 10). The reference is C MuJoCo (float64) at the original's settings (timestep 0.001,
Euler, Newton 100 / 50, tolerance 1e-8, pyramidal cone) on this repo's asset. Every candidate
setting runs through the env itself (``hsa_mjx.make_env`` with config overrides, ``env.step``
under ``lax.scan``), so what passes here is what ships. A setting passes a gait when

    |d_setting - d_reference| / |d_reference| <= 10 %     (d: robot XY displacement, a vector)
    |yaw_setting - yaw_reference| <= 10 degrees           (yaw of the block A -> B axis at the end)

The robot position is the env's ``robot_xy`` (midpoint of the two blocks). Extra rows check the
comparison itself: ``c_perturbed`` (the reference with block A spawned 0.1 mm higher) is its noise
floor, ``c_all_contacts`` (C MuJoCo with every robot geom colliding with every other, as in the
original) validates the contact pruning, the ``C_VARIANTS`` (C MuJoCo at other integrators and
timesteps) separate integration effects from MJX's, and ``mjx_reference`` checks the float32 MJX
port at the reference settings.

    python -m benchmarks.fidelity.guard [--settings NAME ...] [--gaits NAME ...] [--duration 10]
                                  [--out benchmarks/results/fidelity/NAME.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import benchmarks.fidelity.gaits
import hsa_mjx
from benchmarks.fidelity.tables import format_table, summary, summary_table
from benchmarks.run_info import run_info
from hsa_mjx.config import EnvConfig, TerminationConfig, get_preset, with_overrides
from hsa_mjx.sim.model import RobotIndex, load_mj_model, load_robot
from hsa_mjx.task import control
from hsa_mjx.task.termination import FAILURE_REASONS

CONTROL_DT = 0.02
DISPLACEMENT_TOL = 0.10
HEADING_TOL_DEG = 10.0
PERTURBATION_M = 1e-4  # block A spawn-height nudge of the "c_perturbed" twin (noise floor)
# Gaits the guard uses. "wave" is left out: its outcome is chaotic (see docs/speed.md).
GUARD_GAITS = ("extend_contract", "crawl", "sine")

_FAST = {"physics.iterations": 4, "physics.ls_iterations": 8}
_IMPLICIT = {"physics.integrator": "implicitfast"}
_DT2 = {"physics.timestep": 0.002, "control.frame_skip": 10}
_DT4 = {"physics.timestep": 0.004, "control.frame_skip": 5}

# Candidate physics overrides (dotted config keys) over the flat preset; "mjx_reference" is the
# original's settings in MJX. The control period stays 0.02 s (timestep x frame_skip).
SETTINGS: dict[str, dict[str, Any]] = {
    "mjx_reference": {},
    "newton16_ls8": {"physics.iterations": 16, "physics.ls_iterations": 8},
    "newton8_ls8": {"physics.iterations": 8, "physics.ls_iterations": 8},
    "newton4_ls8": dict(_FAST),
    "newton4_ls4": {"physics.iterations": 4, "physics.ls_iterations": 4},
    "newton3_ls4": {"physics.iterations": 3, "physics.ls_iterations": 4},
    "newton2_ls8": {"physics.iterations": 2, "physics.ls_iterations": 8},
    "newton1_ls4": {"physics.iterations": 1, "physics.ls_iterations": 4},
    "newton16_ls8_tol1e-6": {"physics.iterations": 16, "physics.ls_iterations": 8, "physics.tolerance": 1e-6},
    "newton4_ls8_elliptic": {**_FAST, "physics.cone": "elliptic"},
    "implicitfast_dt1ms_newton4_ls8": {**_IMPLICIT, **_FAST},
    "implicitfast_dt1ms_newton8_ls8": {**_IMPLICIT, "physics.iterations": 8, "physics.ls_iterations": 8},
    "implicitfast_dt1ms_newton4_ls4": {**_IMPLICIT, "physics.iterations": 4, "physics.ls_iterations": 4},
    "implicitfast_dt1.25ms_newton4_ls4": {
        **_IMPLICIT,
        "physics.timestep": 0.00125,
        "control.frame_skip": 16,
        "physics.iterations": 4,
        "physics.ls_iterations": 4,
    },
    "implicitfast_dt2ms": {**_IMPLICIT, **_DT2},
    "implicitfast_dt2ms_newton4_ls8": {**_IMPLICIT, **_DT2, **_FAST},
    "implicitfast_dt4ms": {**_IMPLICIT, **_DT4},
    "implicitfast_dt4ms_newton4_ls8": {**_IMPLICIT, **_DT4, **_FAST},
    "euler_dt2ms_newton4_ls8": {**_DT2, **_FAST},
    # The shipped settings on MJX's Warp implementation (MuJoCo Warp; every other setting runs on JAX)
    "warp_implicitfast_dt1ms_newton4_ls8": {**_IMPLICIT, **_FAST, "physics.backend": "warp"},
    "warp_implicitfast_dt1ms_newton8_ls8": {
        **_IMPLICIT,
        "physics.iterations": 8,
        "physics.ls_iterations": 8,
        "physics.backend": "warp",
    },
}
# The settings the training configs use and the throughput harness defaults to, per scene:
# implicitfast at the original 1 ms (explicit Euler blows up under trained gaits: docs/training.md)
# with the fewest Newton iterations that pass every gait (benchmarks/results/fidelity/; every larger
# timestep failed); the plane's is guarded by tests/test_fidelity.py.
SHIPPED_BY_SCENE = {"flat": "implicitfast_dt1ms_newton4_ls8", "terrain": "implicitfast_dt1ms_newton8_ls8"}
SHIPPED = SHIPPED_BY_SCENE["flat"]
# Diagnostics, not candidates: C MuJoCo (float64, full solver) with another integrator or timestep,
# to tell integrator/timestep effects apart from MJX's float32 and short solver.
C_VARIANTS: dict[str, dict[str, Any]] = {
    "c_euler_dt0.5ms": {"physics.timestep": 0.0005, "control.frame_skip": 40},
    "c_implicitfast_dt1ms": dict(_IMPLICIT),
    "c_implicitfast_dt2ms": {**_IMPLICIT, **_DT2},
    "c_implicitfast_dt4ms": {**_IMPLICIT, **_DT4},
}


@dataclasses.dataclass(frozen=True)
class Run:
    """One gait's outcome: robot XY after every control step and the final block-axis yaw."""

    path: np.ndarray  # (steps + 1, 2) robot xy, starting at the reset pose
    yaw_deg: float  # yaw of the block_a -> block_b axis at the end
    failures: dict[str, int]  # control steps on which each failure reason held

    @property
    def displacement(self) -> np.ndarray:
        """Robot XY displacement from the start to the end."""
        return self.path[-1] - self.path[0]


def fidelity_config(overrides: dict[str, Any] | None = None, scene: str = "flat") -> EnvConfig:
    """Flat preset on ``scene``, fixed goal, the JAX backend unless the overrides name another, the given
    physics overrides; checks the control period."""
    config = with_overrides(
        get_preset("flat"), **{"goal.mode": "fixed", "scene": scene, "physics.backend": "jax", **(overrides or {})}
    )
    if not np.isclose(config.dt, CONTROL_DT):
        raise ValueError(f"timestep x frame_skip must stay {CONTROL_DT} s, got {config.dt}")
    return config


def _yaw_deg(block_xy: np.ndarray) -> float:
    """Yaw in degrees of the axis from block A to block B, given their (2, 2) XY positions."""
    axis = block_xy[1] - block_xy[0]
    return float(np.degrees(np.arctan2(axis[1], axis[0])))


def _step_failures(
    worst_qvel: float, worst_qacc: float, z: np.ndarray, finite: bool, limits: TerminationConfig
) -> list[str]:
    """The env's failure reasons for one control step of a C MuJoCo run (flat ground at z = 0)."""
    checks = {
        "non_finite": not finite,
        "block_a_too_high": z[0] > limits.z_max,
        "block_a_too_low": z[0] < limits.z_min,
        "block_b_too_high": z[1] > limits.z_max,
        "block_b_too_low": z[1] < limits.z_min,
        "qvel_limit": worst_qvel > limits.qvel_limit,
        "qacc_limit": worst_qacc > limits.qacc_limit,
    }
    return [name for name, hit in checks.items() if hit]


def plane_start(model: mujoco.MjModel, index: RobotIndex, config: EnvConfig) -> np.ndarray:
    """The env's reset qpos on the plane: the model's qpos0 with both blocks at the spawn height."""
    qpos = model.qpos0.copy()
    qpos[index.block_z] = config.spawn_height
    return qpos


@functools.lru_cache(maxsize=2)
def reference_start(scene: str = "flat") -> tuple[RobotIndex, np.ndarray]:
    """The asset's name index and the env's reset qpos on ``scene`` (the heightfield: from env.reset)."""
    config = fidelity_config(scene=scene)
    if scene == "flat":
        robot = load_robot(config)
        return robot.index, plane_start(robot.mj_model, robot.index, config)
    env = hsa_mjx.make_env(config)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    return env.index, np.asarray(state.pipeline_state.physics.qpos, np.float64)


def robot_self_collision_model(config: EnvConfig) -> mujoco.MjModel:
    """The shipped model with every robot geom (not the floor, not the see-through discs) colliding."""
    model = load_mj_model(config)
    floor = model.geom("floor").id
    for g in range(model.ngeom):
        if g != floor and model.geom_type[g] != mujoco.mjtGeom.mjGEOM_CYLINDER:
            model.geom_contype[g] = 3
            model.geom_conaffinity[g] = 3
    return model


def reference_run(
    actions: np.ndarray,
    scene: str = "flat",
    all_contacts: bool = False,
    lift_m: float = 0.0,
    overrides: dict[str, Any] | None = None,
    start: tuple[RobotIndex, np.ndarray] | None = None,
) -> Run:
    """Play ``actions`` (steps, 8) in C MuJoCo at the original settings, with the env's control law.

    ``all_contacts``: every robot geom collides (the original's set-up). ``lift_m`` raises block A's
    start slightly: a perturbed twin showing how sensitive a gait is (the comparison's noise floor).
    ``overrides``: other physics settings (diagnostics). ``start``: (name index, reset qpos) when the
    caller has them; by default :func:`reference_start` of ``scene``.
    """
    config = fidelity_config(overrides, scene)
    index, qpos0 = start or reference_start(scene)
    model = robot_self_collision_model(config) if all_contacts else load_mj_model(config)
    blocks, ctl = index.block_body, config.control
    data = mujoco.MjData(model)
    data.qpos[:] = qpos0
    data.qpos[index.block_qpos[0] + 2] += lift_m
    mujoco.mj_forward(model, data)
    path, failures = [data.xpos[blocks, :2].mean(axis=0)], {}
    for action in actions:
        start = data.ctrl[index.servo_ids].astype(np.float32)
        end = control.next_targets(start, jnp.asarray(action), ctl.max_increment, ctl.servo_target_limit)
        worst_qvel = worst_qacc = 0.0
        for target in np.asarray(control.substep_targets(start, end, ctl.frame_skip, ctl.smooth_positions)):
            data.ctrl[index.servo_ids] = target
            mujoco.mj_step(model, data)
            worst_qvel = max(worst_qvel, float(np.abs(data.qvel).max()))
            worst_qacc = max(worst_qacc, float(np.abs(data.qacc).max()))
        finite = bool(np.isfinite(data.qpos).all() and np.isfinite(data.qacc).all())
        for reason in _step_failures(worst_qvel, worst_qacc, data.xpos[blocks, 2], finite, config.termination):
            failures[reason] = failures.get(reason, 0) + 1
        path.append(data.xpos[blocks, :2].mean(axis=0))
    return Run(np.asarray(path), _yaw_deg(data.xpos[blocks, :2]), failures)


def mjx_rollout_fn(env: hsa_mjx.HSAEnv) -> Callable:
    """jit(vmap) of: reset, then ``env.step`` over an action sequence; returns block XY per step."""
    blocks = env.index.block_body

    def rollout(actions: jax.Array) -> tuple[jax.Array, jax.Array, dict[str, jax.Array]]:
        state = env.reset(jax.random.PRNGKey(0))

        def body(state, action):
            state = env.step(state, action)
            fails = {r: state.metrics[f"termination/{r}"] for r in FAILURE_REASONS}
            return state, (state.pipeline_state.physics.xpos[blocks, :2], fails)

        _, (xy, fails) = jax.lax.scan(body, state, actions)
        start = state.pipeline_state.physics.xpos[blocks, :2]
        return start, xy, jax.tree.map(jnp.sum, fails)

    return jax.jit(jax.vmap(rollout))


def mjx_runs(overrides: dict[str, Any], actions: np.ndarray, scene: str = "flat") -> tuple[list[Run], float, float]:
    """Play each gait (actions (gaits, steps, 8)) through the env; return runs, compile s, run s."""
    env = hsa_mjx.make_env(fidelity_config(overrides, scene), num_envs=actions.shape[0])
    fn = mjx_rollout_fn(env)
    tic = time.perf_counter()
    compiled = fn.lower(jnp.asarray(actions)).compile()
    compile_s = time.perf_counter() - tic
    tic = time.perf_counter()
    start, xy, fails = jax.block_until_ready(compiled(jnp.asarray(actions)))
    run_s = time.perf_counter() - tic
    start, xy = np.asarray(start, np.float64), np.asarray(xy, np.float64)
    runs = []
    for g in range(actions.shape[0]):
        path = np.concatenate([start[g][None], xy[g]]).mean(axis=1)
        counts = {r: int(v[g]) for r, v in fails.items() if int(v[g])}
        runs.append(Run(path, _yaw_deg(xy[g, -1]), counts))
    return runs, compile_s, run_s


def compare(reference: Run, candidate: Run) -> dict[str, Any]:
    """Displacement error (vector, relative), heading error and the pass verdict."""
    d_ref, d_cand = reference.displacement, candidate.displacement
    norm_ref = float(np.linalg.norm(d_ref))
    error = float(np.linalg.norm(d_cand - d_ref)) / max(norm_ref, 1e-9)
    heading = abs((candidate.yaw_deg - reference.yaw_deg + 180.0) % 360.0 - 180.0)
    steps = min(len(reference.path), len(candidate.path))
    drift = float(np.max(np.linalg.norm(candidate.path[:steps] - reference.path[:steps], axis=1)))
    finite = bool(np.all(np.isfinite(candidate.path))) and "non_finite" not in candidate.failures
    new_failures = sorted(set(candidate.failures) - set(reference.failures))
    ok = finite and error <= DISPLACEMENT_TOL and heading <= HEADING_TOL_DEG and not new_failures
    return {
        "displacement_m": [round(float(v), 5) for v in d_cand],
        "distance_m": round(float(np.linalg.norm(d_cand)), 5),
        "reference_distance_m": round(norm_ref, 5),
        "displacement_error_pct": round(100.0 * error, 2),
        "distance_error_pct": round(100.0 * (float(np.linalg.norm(d_cand)) - norm_ref) / max(norm_ref, 1e-9), 2),
        "heading_error_deg": round(float(heading), 2),
        "max_path_deviation_m": round(drift, 5),
        "yaw_deg": round(candidate.yaw_deg, 2),
        "failures": candidate.failures,
        "failures_not_in_reference": new_failures,
        "pass": bool(ok),
    }


def gait_matrix(gait_names: Sequence[str], duration_s: float) -> np.ndarray:
    """Actions of every gait, shape (gaits, steps, 8), with the layout read from the asset."""
    layout = benchmarks.fidelity.gaits.gait_layout(load_mj_model(fidelity_config()))
    steps = int(round(duration_s / CONTROL_DT))
    return np.stack([benchmarks.fidelity.gaits.gait_actions(name, layout, steps, CONTROL_DT) for name in gait_names])


def references(actions: np.ndarray, scene: str, **kwargs: Any) -> tuple[list[Run], float]:
    """C MuJoCo runs of every gait (``reference_run`` options as keywords) and their seconds."""
    tic = time.perf_counter()
    runs = [reference_run(a, scene, **kwargs) for a in actions]
    return runs, time.perf_counter() - tic


def rows_for(
    setting: str, runs: list[Run], refs: list[Run], gait_names: Sequence[str], timing: dict[str, float]
) -> list[dict[str, Any]]:
    """One result row per gait: the comparison plus the setting's overrides and timings."""
    overrides = SETTINGS.get(setting, C_VARIANTS.get(setting, {}))
    return [
        {"setting": setting, "gait": gait, "overrides": overrides, **timing, **compare(ref, run)}
        for gait, ref, run in zip(gait_names, refs, runs)
    ]


def run_fidelity(
    settings: Sequence[str],
    gait_names: Sequence[str],
    duration_s: float,
    check_contacts: bool = True,
    c_variants: Sequence[str] = tuple(C_VARIANTS),
    scene: str = "flat",
    log: bool = True,
) -> list[dict[str, Any]]:
    """Compare every setting (and the C MuJoCo diagnostics) against the C MuJoCo reference."""
    unknown = sorted(set(settings) - set(SETTINGS)) + sorted(set(c_variants) - set(C_VARIANTS))
    if unknown:
        raise ValueError(f"unknown setting(s) {unknown}; available: {sorted(SETTINGS)} and {sorted(C_VARIANTS)}")
    actions = gait_matrix(gait_names, duration_s)
    refs, ref_s = references(actions, scene)
    rows = rows_for("c_reference", refs, refs, gait_names, {"run_s": round(ref_s, 2)})
    checks = {"c_perturbed": {"lift_m": PERTURBATION_M}}
    if check_contacts:
        checks["c_all_contacts"] = {"all_contacts": True}
    checks.update({name: {"overrides": C_VARIANTS[name]} for name in c_variants})
    for name, options in checks.items():
        runs, run_s = references(actions, scene, **options)
        rows += rows_for(name, runs, refs, gait_names, {"run_s": round(run_s, 2)})
    for name in settings:
        runs, compile_s, run_s = mjx_runs(SETTINGS[name], actions, scene)
        rows += rows_for(name, runs, refs, gait_names, {"compile_s": round(compile_s, 2), "run_s": round(run_s, 2)})
        if log:
            print(f"  {name}: compile {compile_s:.1f} s, run {run_s:.1f} s", flush=True)
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--settings",
        nargs="*",
        default=list(SETTINGS),
        choices=sorted(SETTINGS),
        metavar="NAME",
        help=f"MJX settings to test (default all): {', '.join(SETTINGS)}",
    )
    parser.add_argument(
        "--gaits", nargs="+", default=list(GUARD_GAITS), choices=sorted(benchmarks.fidelity.gaits.GAITS)
    )
    parser.add_argument("--duration", type=float, default=10.0, help="seconds of simulated time per gait")
    parser.add_argument("--no-contact-check", action="store_true", help="skip the all-contacts C reference")
    parser.add_argument(
        "--c-variants",
        nargs="*",
        default=list(C_VARIANTS),
        choices=sorted(C_VARIANTS),
        help="C MuJoCo diagnostic settings (none: skip)",
    )
    parser.add_argument(
        "--scene",
        choices=("flat", "terrain"),
        default="flat",
        help="flat: the plane (the guard); terrain: the flat-data heightfield",
    )
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/fidelity/fidelity.json"))
    args = parser.parse_args(argv)
    rows = run_fidelity(
        args.settings, args.gaits, args.duration, not args.no_contact_check, args.c_variants, args.scene
    )
    print(format_table(rows))
    verdict = summary(rows)
    print("\n" + summary_table(rows))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        **run_info(),
        "scene": args.scene,
        "duration_s": args.duration,
        "gaits": args.gaits,
        "tolerance": {"displacement_pct": 100 * DISPLACEMENT_TOL, "heading_deg": HEADING_TOL_DEG},
        "reference": f"C MuJoCo, timestep 0.001, Euler, Newton 100/50, tol 1e-8, pyramidal, scene {args.scene}",
    }
    args.out.write_text(json.dumps({"meta": meta, "passes_every_gait": verdict, "rows": rows}, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

"""Evaluation plots (the original's diagnostics plus trajectories) and an offscreen-rendered GIF."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from matplotlib.figure import Figure
from PIL import Image

from hsa_mjx.task import goals

SERVO_LABELS = ("1A", "2A", "3A", "4A", "1C", "2C", "3C", "4C")
# Frames per GIF at most: offscreen rendering without a GPU (Mesa's llvmpipe) takes a good part of a
# second a frame, so a 1,000-step episode at every 2nd step would take minutes to draw.
GIF_FRAMES = 120


def _episode(traces: dict, key: str, episode: int = 0) -> np.ndarray:
    """The live part of one episode's trace."""
    alive = traces["alive"][episode].astype(bool)
    return traces[key][episode][alive]


def plot_actions(traces: dict, path: Path) -> Path:
    """Action distribution per servo (all episodes) and action smoothness (|delta a| per step)."""
    alive = traces["alive"].astype(bool)
    actions = traces["action"][alive]
    delta = np.abs(np.diff(traces["action"], axis=1))[alive[:, 1:]]
    fig = Figure(figsize=(12, 4), layout="constrained")
    axes = fig.subplots(1, 2)
    axes[0].violinplot([actions[:, i] for i in range(actions.shape[1])], showmeans=True)
    axes[0].set_xticks(range(1, actions.shape[1] + 1), SERVO_LABELS[: actions.shape[1]])
    axes[0].set_title("action distribution per servo")
    axes[1].boxplot([delta[:, i] for i in range(delta.shape[1])], showfliers=False)
    axes[1].set_xticks(range(1, delta.shape[1] + 1), SERVO_LABELS[: delta.shape[1]])
    axes[1].set_title(f"action smoothness |a_t - a_t-1| (mean {delta.mean():.3f})")
    fig.savefig(path, dpi=90)
    return path


def plot_joints(traces: dict, dt: float, path: Path) -> Path:
    """Actuated joint positions and velocities over time (first episode)."""
    pos, vel = _episode(traces, "joint_pos"), _episode(traces, "joint_vel")
    t = np.arange(len(pos)) * dt
    fig = Figure(figsize=(11, 6), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for i in range(pos.shape[1]):
        axes[0].plot(t, pos[:, i], label=SERVO_LABELS[i], lw=0.9)
        axes[1].plot(t, vel[:, i], lw=0.9)
    axes[0].set_ylabel("position (rad)")
    axes[1].set_ylabel("velocity (rad/s)")
    axes[1].set_xlabel("time (s)")
    axes[0].legend(ncol=8, fontsize=7)
    axes[0].set_title("actuated joints, episode 0")
    fig.savefig(path, dpi=90)
    return path


def plot_constraint(traces: dict, pairs: np.ndarray, dt: float, path: Path) -> Path:
    """Paired-joint (A, C) angle differences against the pi limit (first episode)."""
    pos = _episode(traces, "joint_pos")
    t = np.arange(len(pos)) * dt
    fig = Figure(figsize=(11, 3.5), layout="constrained")
    ax = fig.subplots()
    for unit, (a, c) in enumerate(pairs):
        ax.plot(t, np.abs(pos[:, a] - pos[:, c]), label=f"unit {unit + 1}", lw=0.9)
    ax.axhline(np.pi, color="k", ls="--", lw=0.8, label="pi")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("|q_A - q_C| (rad)")
    ax.legend(ncol=5, fontsize=8)
    ax.set_title("paired-joint constraint difference, episode 0")
    fig.savefig(path, dpi=90)
    return path


def plot_trajectories(traces: dict, path: Path) -> Path:
    """XY paths of every episode with start and goal (success in green, failure in red)."""
    fig = Figure(figsize=(7, 7), layout="constrained")
    ax = fig.subplots()
    for e in range(traces["xy"].shape[0]):
        xy, goal = _episode(traces, "xy", e), _episode(traces, "goal", e)
        if len(xy) == 0:
            continue
        ok = _episode(traces, "success", e)[-1] > 0.5
        ax.plot(xy[:, 0], xy[:, 1], color="tab:green" if ok else "tab:red", lw=1)
        ax.plot(*goal[-1], marker="*", color="tab:orange", ms=10)
    ax.plot(0, 0, "ko", ms=5)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_title("robot paths (green: reached goal) and goals (stars)")
    fig.savefig(path, dpi=90)
    return path


GOAL_RGBA = (1.0, 0.0, 1.0, 0.9)  # the goal: a magenta pole (a colour the robot and ground do not have)
CHECKPOINT_RGBA = (0.0, 0.9, 0.9, 0.6)  # the spiral's checkpoints: cyan poles


def _pole(scene: mujoco.MjvScene, xy: np.ndarray, rgba: tuple, height: float = 0.8, radius: float = 0.04) -> None:
    """Stand a marker pole on ``xy`` in ``scene`` (a geom of the scene only: the model is unchanged)."""
    if scene.ngeom >= scene.maxgeom:
        return
    mujoco.mjv_initGeom(
        scene.geoms[scene.ngeom],
        mujoco.mjtGeom.mjGEOM_CYLINDER,
        np.array([radius, height / 2, 0.0]),
        np.array([xy[0], xy[1], height / 2]),
        np.eye(3).reshape(-1),
        np.asarray(rgba, np.float32),
    )
    scene.ngeom += 1


def _framing_camera(robot_xy: np.ndarray, goal_xy: np.ndarray) -> mujoco.MjvCamera:
    """A camera looking down at the robot and its goal together, from the same side every frame."""
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = [*(0.5 * (robot_xy + goal_xy)), 0.0]
    camera.distance = 1.5 + 1.1 * float(np.linalg.norm(goal_xy - robot_xy))
    camera.azimuth, camera.elevation = 90.0, -50.0
    return camera


def render_gif(
    traces: dict, env, path: Path, every: int = 2, size: tuple[int, int] = (360, 480), max_frames: int = GIF_FRAMES
) -> Path:
    """Render episode 0 offscreen to an animated GIF playing in real time, every ``every``-th step,
    fewer for long episodes so that it holds at most ``max_frames`` frames. The camera frames the robot
    and its goal, marked by a magenta pole (the spiral's checkpoints by cyan ones). MuJoCo's offscreen
    platform is the one chosen before it was imported (``train.evaluate``)."""
    model = env.robot.mj_model
    data = mujoco.MjData(model)
    qpos, goal = _episode(traces, "qpos"), _episode(traces, "goal")
    every = max(every, -(-len(qpos) // max_frames))
    goal_config = env.config.goal
    checkpoints = (
        goals.spiral_checkpoints(goal_config, env.config.terrain.spiral) if goal_config.mode == "spiral" else []
    )
    frames = []
    with mujoco.Renderer(model, *size) as renderer:
        for t in range(0, len(qpos), every):
            data.qpos[:] = qpos[t]
            data.mocap_pos[env.index.goal_mocap, :2] = goal[t]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=_framing_camera(data.subtree_com[0, :2], np.asarray(goal[t])))
            for xy in checkpoints:
                _pole(renderer.scene, xy, CHECKPOINT_RGBA, height=0.5)
            _pole(renderer.scene, goal[t], GOAL_RGBA)
            frames.append(Image.fromarray(renderer.render()))
    duration_ms = int(1000 * env.dt * every)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=duration_ms, loop=0)
    return path


def write_all(traces: dict, env, out: Path, video: bool = False) -> list[Path]:
    """Every diagnostic plot (and the GIF when ``video``) into ``out``."""
    pairs = np.asarray(env.index.constraint_pairs)
    written = [
        plot_actions(traces, out / "actions.png"),
        plot_joints(traces, env.dt, out / "joints.png"),
        plot_constraint(traces, pairs, env.dt, out / "constraint.png"),
        plot_trajectories(traces, out / "trajectories.png"),
    ]
    if video:
        written.append(render_gif(traces, env, out / "episode.gif"))
    return written


MODE_COLOURS = {"reached": "tab:green", "terminated": "tab:red", "stuck": "tab:gray", "lost": "tab:purple"}
MODE_COLOURS["slow"] = "tab:olive"


def failure_modes(rows: list[dict], path: Path) -> Path:
    """How each (type, difficulty) cell's episodes ended, one stacked bar each, a panel per difficulty:
    reached, terminated, and the time-outs' modes (stuck, lost, slow; ``train.episodes.failures``)."""
    levels = sorted({r["difficulty"] for r in rows})
    types = list(dict.fromkeys(r["type"] for r in rows))
    cell = {(r["type"], r["difficulty"]): r for r in rows}
    fig = Figure(figsize=(3.5 + 3.2 * len(levels), 1.4 + 0.35 * len(types)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(levels), sharey=True))
    for ax, level in zip(axes, levels):
        left = np.zeros(len(types))
        for mode, colour in MODE_COLOURS.items():
            share = np.array([cell[(t, level)]["modes"][mode] for t in types])
            ax.barh(range(len(types)), share, left=left, color=colour, label=mode)
            left += share
        ax.set_xlim(0, 1)
        ax.set_title(f"difficulty {level:g}")
        ax.set_yticks(range(len(types)), types)
        ax.invert_yaxis()
        ax.set_xlabel("share of episodes")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=7)
    fig.savefig(path, dpi=100)
    return Path(path)

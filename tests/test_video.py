"""``python -m train.evaluate --video`` on a machine without a display or ``MUJOCO_GL``: the command
chooses MuJoCo's offscreen platform itself, and the GIF shows the goal (the spiral's checkpoints too)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from train.episodes import diagnostics

ROOT = Path(__file__).resolve().parents[1]


def _share(frame: np.ndarray, rgba: tuple) -> float:
    """The share of a frame's pixels near a marker's colour (the lit side of the pole)."""
    target = 255 * np.asarray(rgba[:3])
    return float((np.abs(frame.astype(float) - target).max(axis=-1) < 60).mean())


def _evaluate_args(policy: str, out: Path) -> list[str]:
    """``train.evaluate``'s arguments for a one-episode, four-step video of a shipped policy."""
    return ["--policy", policy, "--video", "--episodes", "1", "--steps", "4", "--out", str(out)]


def _first_frame(out: Path) -> np.ndarray:
    """The first frame of the GIF an evaluation wrote."""
    with Image.open(out / "episode.gif") as gif:
        return np.asarray(gif.convert("RGB"))


def test_video_renders_headless_and_marks_the_goal(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    out = tmp_path / "eval"
    done = subprocess.run(
        [sys.executable, "-m", "train.evaluate", *_evaluate_args("flat", out)],
        cwd=ROOT,
        env={**env, "JAX_PLATFORMS": "cpu"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert _share(_first_frame(out), diagnostics.GOAL_RGBA) > 1e-3  # the goal's pole is in the picture


def test_spiral_video_marks_the_goal_and_the_track_checkpoints(tmp_path):
    """In this process (the GL platform already chosen): the spiral's goal and its track's checkpoints."""
    from train.evaluate import main as evaluate

    assert evaluate(_evaluate_args("spiral", tmp_path)) == 0
    frame = _first_frame(tmp_path)
    assert _share(frame, diagnostics.GOAL_RGBA) > 1e-3
    assert _share(frame, diagnostics.CHECKPOINT_RGBA) > 1e-3

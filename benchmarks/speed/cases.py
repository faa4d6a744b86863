"""What the throughput harness measures: its terrains and its observations, each as env overrides.

``TERRAINS``: the plane, and the terrain scene drawing every random and deterministic type but the
spiral, plain, with goals on reachable ground, or with progress along the ground. ``OBSERVATIONS``: the
original's, the rough task's heading with and without the height scan, the randomised flat task, and the
four corners of the robustness benchmark's stress grid.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import hsa_mjx
from hsa_mjx.resources import config_path, read_yaml
from hsa_mjx.terrain import TERRAIN_TYPES

HEIGHTFIELD_TYPES = [t for t in TERRAIN_TYPES if t != "spiral"]  # the spiral needs spiral goals
TERRAINS: dict[str, dict[str, Any]] = {
    "flat": {"scene": "flat"},
    "heightfield": {"scene": "terrain", "terrain.types": HEIGHTFIELD_TYPES},
    # the same with goals on reachable ground (terrain.reachability; the corridor as configs/corridor.yaml
    # draws it, since the dispatcher's has no reachable goal ground at full wall height)
    "heightfield_reachable": {
        "scene": "terrain",
        "terrain.types": HEIGHTFIELD_TYPES,
        "terrain.reachability.enabled": True,
        "terrain.corridor.corridor_width": 0.62,
        "terrain.corridor.center": 0.510204,
    },
    # and with progress measured along the ground (32 goal sites a tile, reward.progress geodesic)
    "heightfield_geodesic": {
        "scene": "terrain",
        "terrain.types": HEIGHTFIELD_TYPES,
        "terrain.reachability.enabled": True,
        "terrain.reachability.goal_sites": 32,
        "reward.progress": "geodesic",
        "terrain.corridor.corridor_width": 0.62,
        "terrain.corridor.center": 0.510204,
    },
}


# observations the env computes: the original's 24 values, or the rough task's heading (28) with the
# 63-point height scan (the scan's cost is measured against "heading", the same observation without it)
def _randomized() -> dict[str, Any]:
    """configs/train_flat_dr.yaml's randomisation and observation noise as dotted env overrides."""
    env = read_yaml(config_path("train_flat_dr"))["env"]
    return {
        **{f"randomization.{k}": v for k, v in env["randomization"].items()},
        **{f"observation.noise.{k}": v for k, v in env["observation"]["noise"].items()},
    }


def _stress_corner(number: int) -> dict[str, Any]:
    """Corner ``number`` (1-4) of the robustness benchmark's stress grid as one fixed model for every env:
    each range collapsed to the corner's value, its latency, pushes and noise, no ``qacc_limit`` rule
    (so the NaN check alone guards the state)."""
    from benchmarks.robustness import grids
    from hsa_mjx.deploy.loop import latency_steps

    corner = grids.stress_grid()[-4:][number - 1]
    out: dict[str, Any] = {"observation.heading": True, "termination.qacc_termination": False}
    out.update({f"randomization.{k}": [corner[k]] * 2 for k in grids.SCALES if corner[k] != 1.0})
    if corner["servo_torque_limit"] is not None:
        out["randomization.servo_force_limit"] = [corner["servo_torque_limit"]] * 2
    delay = latency_steps(corner["latency_ms"], hsa_mjx.build_config("flat").dt)
    out["randomization.latency_steps"] = [delay, delay]
    if corner["pushes"]:
        out.update(
            {"randomization.push_interval_s": list(grids.PUSH_INTERVAL_S), "randomization.push_speed": grids.PUSH_SPEED}
        )
    if corner["noise"]:
        out.update({f"observation.noise.{k}": v for k, v in grids.NOISE.items()})
    return out


# "heading+randomized": "heading" with the randomised flat task's per-env model, latency, pushes and
# noise (docs/robustness.md; its cost is measured against "heading"), read from its config when used;
# "stress_corner1".."stress_corner4": every env on one corner model of the stress grid (random actions
# there are the stability check at the extremes)
OBSERVATIONS: dict[str, Callable[[], dict[str, Any]]] = {
    "original": dict,
    "heading": lambda: {"observation.heading": True},
    "heading+scan": lambda: {
        "observation.heading": True,
        "observation.height_scan.enabled": True,
        "observation.height_scan.noise": 0.02,
    },
    "heading+randomized": lambda: {"observation.heading": True, **_randomized()},
    **{f"stress_corner{i}": (lambda i=i: _stress_corner(i)) for i in range(1, 5)},
}

"""The terrain task presets as plain config mappings (merged over the flat preset by ``hsa_mjx.config``).

``corridor`` and ``spiral`` take the original's ``corridor_config.yaml`` and ``ppo_position.yaml``
(hsaLooseModel: servo range 6.28; their reward weights, episode lengths and checkpoint settings);
``craters`` and ``mixed`` keep the flat preset's weights on terrain. The YAML files in
``configs/`` hold the same values (a test checks that they agree).
"""

from __future__ import annotations

_LOOSE_MODEL = {"servo_target_limit": 6.28}
# The original's corridor floor at the 50-vertex grid: three vertex rows at height 0 (y = -0.102,
# 0.102, 0.306) and full-height walls from the next row on. A grid of 50 vertices has no row at
# y = 0, so a floor of three rows cannot be centred on the robot: the original's +0.102 m offset is
# kept on purpose. Centred instead (width 0.6, centre 0.5), the floor is flat only between the rows
# at +-0.102 m and the feet stand on the walls' ramps; open-loop gaits then barely move (docs/terrain.md).
_ORIGINAL_CORRIDOR = {"corridor_width": 0.62, "center": 0.510204}  # centre: the row at 0.5 + 0.5 / 49
# The original's spiral floor: it zeroed every vertex within 0.4 m of the line (track_width 0.8) and
# raised all others, so the floor reached the first raised vertex. Our walls put their half height at
# track_width / 2, which at 0.8 m leaves a floor one vertex spacing narrower (median 0.46 m across
# the track, original 0.60 m); at 0.95 m the median is 0.62 m (docs/terrain.md).
_ORIGINAL_SPIRAL_FLOOR = {"track_width": 0.95}
_TRACK_REWARD = {"ctrl": 0.0, "contact": 0.0, "lateral": 0.0, "constraint": 0.05, "acceleration": 1e-5,
                 "joint_velocity": 5e-4, "stagnation": 0.1, "alive": 0.0}

MIXED_TYPES = {
    "flat": 0.15, "wavy": 0.1, "perlin": 0.1, "stairs": 0.1, "incline": 0.1, "craters": 0.15,
    "poles": 0.1, "flat_with_incline": 0.1, "flat_with_ramp": 0.1,
}

TERRAIN_PRESETS: dict[str, dict] = {
    "craters": {"name": "craters", "scene": "terrain", "terrain_type": "craters"},
    "corridor": {
        "name": "corridor", "scene": "terrain", "terrain_type": "corridor",
        "control": _LOOSE_MODEL,
        "reward": dict(_TRACK_REWARD, forward=10.0, distance=20.0),
        "termination": {"max_episode_steps": 4000},
        "terrain": {"flat_spawn": {"enabled": False},  # as corridor_config (ensure_flat_spawn: false)
                    "corridor": _ORIGINAL_CORRIDOR},
    },
    "spiral": {
        "name": "spiral", "scene": "terrain", "terrain_type": "spiral",
        "control": _LOOSE_MODEL,
        "reward": dict(_TRACK_REWARD, forward=15.0, distance=30.0, checkpoint=200.0),
        "termination": {"max_episode_steps": 8000},
        "goal": {"mode": "spiral", "num_checkpoints": 8, "checkpoint_radius": 0.4,
                 "spiral_start_radius": 0.5, "spiral_end_radius": 4.0, "spiral_turns": 2.0},
        # The track carves its own start disc; the original's spawn zone also cut the first wall.
        "terrain": {"flat_spawn": {"enabled": False}, "spiral": _ORIGINAL_SPIRAL_FLOOR},
    },
    "mixed": {
        "name": "mixed", "scene": "terrain",
        "terrain": {"types": list(MIXED_TYPES), "proportions": list(MIXED_TYPES.values())},
    },
}

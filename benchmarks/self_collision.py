"""Evidence for dropping robot self-collision: count robot-robot contacts in C MuJoCo.

Loads the shipped flat scene, turns on collisions between every pair of robot geoms (the
original let all robot geoms collide with each other), drives the servos with random
increments (the original's action semantics, max_increment 0.1785, frame_skip 20) and counts
contacts between two robot geoms (penetrating or within the margin).

    python -m benchmarks.self_collision --episodes 5 --steps 1000
"""

from __future__ import annotations

import argparse
import json

import mujoco
import numpy as np

from hsa_mjx.config import EnvConfig
from hsa_mjx.model import load_mj_model


def robot_self_collision_model(config: EnvConfig) -> mujoco.MjModel:
    """The shipped model with every robot geom (not the floor, not the see-through discs) colliding."""
    model = load_mj_model(config)
    floor = model.geom("floor").id
    for g in range(model.ngeom):
        if g != floor and model.geom_type[g] != mujoco.mjtGeom.mjGEOM_CYLINDER:
            model.geom_contype[g] = 3
            model.geom_conaffinity[g] = 3
    return model


def count_self_contacts(episodes: int, steps: int, seed: int, amplitude: float) -> dict:
    """Run random-increment episodes and count robot-robot contacts per physics step."""
    config = EnvConfig()
    model = robot_self_collision_model(config)
    floor = model.geom("floor").id
    rng = np.random.default_rng(seed)
    pairs: dict[str, int] = {}
    physics_steps = hits = 0
    for _ in range(episodes):
        data = mujoco.MjData(model)
        for _ in range(steps):
            target = data.ctrl + config.control.max_increment * amplitude * rng.uniform(-1, 1, model.nu)
            data.ctrl[:] = np.clip(target, -config.control.servo_target_limit, config.control.servo_target_limit)
            for _ in range(config.control.frame_skip):
                mujoco.mj_step(model, data)
                physics_steps += 1
                robot = [c for c in data.contact[:data.ncon] if floor not in c.geom]
                hits += bool(robot)
                for c in robot:
                    key = "/".join(sorted(model.geom(g).name or f"geom{g}" for g in c.geom))
                    pairs[key] = pairs.get(key, 0) + 1
    return {"physics_steps": physics_steps, "steps_with_self_contact": hits, "pairs": pairs,
            "episodes": episodes, "env_steps_per_episode": steps, "seed": seed, "amplitude": amplitude}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--amplitude", type=float, default=1.0, help="scale of the random actions")
    args = parser.parse_args()
    print(json.dumps(count_self_contacts(args.episodes, args.steps, args.seed, args.amplitude), indent=2))


if __name__ == "__main__":
    main()

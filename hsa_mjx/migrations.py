"""Every key that older configs, policy files and checkpoints hold, mapped onto today's keys.

Configs are plain nested dicts here, before any dataclass is built, so that a file written by an
earlier version loads as the config it meant. Each rule names what it maps; a value that contradicts
today's key is refused (``ValueError``) rather than silently dropped.

Env config (``env_keys``):

- ``terrain_type: X`` is a shorthand for ``terrain.types: [X]`` (``mixed`` for several types, given
  in ``terrain.types``);
- ``goal.spiral_start_radius`` / ``spiral_end_radius`` / ``spiral_turns`` are ``terrain.spiral``'s
  ``start_radius`` / ``end_radius`` / ``turns`` (the checkpoints lie on the track);
- the reward weights ``lateral``, ``ctrl``, ``contact``, ``constraint``, ``acceleration``,
  ``joint_velocity`` and ``stagnation`` carry their terms' names: ``lateral_cost``, ``ctrl_cost``, ...;
- ``servo.preset: NAME`` named a servo class: it is the robot profile ``robot: NAME`` (``hsa_mjx.robots``;
  refused where no profile has that name), an empty one is dropped; ``randomization.servo_presets`` is
  ``randomization.robots``.

Training config (``training_keys``), after ``env_keys`` on its ``env`` section:

- ``curriculum:`` is ``goal_curriculum:`` (beside ``terrain_curriculum:``);
- ``curriculum.initial_range`` stated the goal curriculum's start again: it is ``env.goal.radial_range``
  (refused where both are given and differ; dropped with the curriculum off, where it did nothing);
- ``run.multi_device`` is ``run.collection`` (``per_device`` is ``thread_per_device``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

MIXED = "mixed"  # terrain_type of a batch drawing from several types
SPIRAL_GOAL_KEYS = {"spiral_start_radius": "start_radius", "spiral_end_radius": "end_radius", "spiral_turns": "turns"}
SECTION_NAMES = {"curriculum": "goal_curriculum"}  # older training config section -> today's
REWARD_WEIGHTS = {  # older reward weight name -> its term's name (the weight's name today)
    name: f"{name}_cost"
    for name in ("lateral", "ctrl", "contact", "constraint", "acceleration", "joint_velocity", "stagnation")
}
OLD_COLLECTION = {"auto": "auto", "pmap": "pmap", "per_device": "thread_per_device"}  # run.multi_device values


def env_keys(data: Mapping[str, Any], terrain_types: tuple[str, ...]) -> dict:
    """An env config mapping with older keys moved to today's (``terrain_types``: the valid type names)."""
    data = dict(data)
    section = data.get("terrain")
    section = dict(section) if isinstance(section, Mapping) else ({} if section is None else section)
    if "terrain_type" in data:
        _terrain_type_into(data.pop("terrain_type"), section, terrain_types)
    goal = data.get("goal")
    if isinstance(goal, Mapping) and isinstance(section, dict) and any(k in goal for k in SPIRAL_GOAL_KEYS):
        data["goal"], section["spiral"] = _spiral_keys(dict(goal), dict(section.get("spiral") or {}))
    if section != {} or "terrain" in data:
        data["terrain"] = section
    if isinstance(data.get("reward"), Mapping):
        reward = dict(data["reward"])
        _move_keys(reward, reward, REWARD_WEIGHTS, ("reward", "reward"))
        data["reward"] = reward
    _servo_classes_into_robots(data)
    return data


def _servo_classes_into_robots(data: dict) -> None:
    """``servo.preset`` as ``robot``, ``randomization.servo_presets`` as ``randomization.robots`` (in place)."""
    servo = data.get("servo")
    if isinstance(servo, Mapping) and "preset" in servo:
        servo = dict(servo)
        name = servo.pop("preset")
        data["servo"] = servo
        if name:
            from hsa_mjx.robots import profile_names  # the profiles are package data: read on use

            if name not in profile_names():
                raise ValueError(
                    f"config key 'servo.preset' = {name!r}: servo classes are robot profiles now ('robot: NAME'), "
                    f"and none is named {name!r}; profiles: {profile_names()}"
                )
            if data.get("robot", name) != name:
                raise ValueError(f"config keys 'servo.preset' = {name!r} and 'robot' = {data['robot']!r} differ")
            data["robot"] = name
    rand = data.get("randomization")
    if isinstance(rand, Mapping) and "servo_presets" in rand:
        rand = dict(rand)
        _move_keys(rand, rand, {"servo_presets": "robots"}, ("randomization", "randomization"))
        data["randomization"] = rand


def _move_keys(source: dict, target: dict, names: Mapping[str, str], paths: tuple[str, str], why: str = "") -> None:
    """Move each older key of ``source`` to today's name in ``target`` (the same dict or another);
    ``paths``: the two sections' dotted names, for the ValueError where an older and a newer value differ."""
    for old, new in names.items():
        if old in source:
            value = source.pop(old)
            if new in target and target[new] != value:
                raise ValueError(
                    f"config key '{paths[0]}.{old}' = {value!r} differs from '{paths[1]}.{new}' = "
                    f"{target[new]!r}; set '{paths[1]}.{new}' alone{why}"
                )
            target[new] = value


def _spiral_keys(goal: dict, spiral: dict) -> tuple[dict, dict]:
    """The goal section's old spiral keys moved into the terrain's spiral section."""
    _move_keys(goal, spiral, SPIRAL_GOAL_KEYS, ("goal", "terrain.spiral"), " (the checkpoints follow it)")
    return goal, spiral


def _terrain_type_into(kind: Any, section: dict, terrain_types: tuple[str, ...]) -> None:
    """Put the ``terrain_type`` shorthand into the terrain section (checked against its types)."""
    if kind != MIXED and kind not in terrain_types:
        raise ValueError(
            f"config key 'terrain_type' = {kind!r} is not valid; choose one of "
            f"{list(terrain_types) + [MIXED]} (a shorthand for terrain.types: [TYPE])"
        )
    types = section.get("types") if isinstance(section, dict) else None
    if types is None:
        if kind == MIXED:
            raise ValueError(f"terrain_type '{MIXED}' needs 'terrain.types' (the types to draw from)")
        section.update(types=[kind], proportions=[1.0])
    elif (list(types) != [kind]) if kind != MIXED else len(types) < 2:
        raise ValueError(
            f"config key 'terrain_type' = {kind!r} does not match 'terrain.types' = {list(types)}; "
            f"set 'terrain.types' alone"
        )


def training_keys(data: Mapping[str, Any]) -> dict:
    """A training config mapping with older section and key names moved to today's (env keys untouched)."""
    data = dict(data)
    for old, new in SECTION_NAMES.items():
        if old in data:
            if new in data:
                raise ValueError(f"config sections '{old}' and '{new}' are the same: give '{new}'")
            data[new] = data.pop(old)
    data["env"], data["goal_curriculum"] = _start_range_in_env(data.get("env"), data.get("goal_curriculum"))
    if data["goal_curriculum"] is None:
        del data["goal_curriculum"]
    if data["env"] is None:
        del data["env"]
    run = data.get("run")
    if isinstance(run, Mapping) and "multi_device" in run:
        data["run"] = _collection_key(dict(run))
    return data


def _start_range_in_env(env: Any, curriculum: Any) -> tuple[Any, Any]:
    """``goal_curriculum.initial_range`` moved into ``env.goal.radial_range`` (see the module doc)."""
    if not (isinstance(curriculum, Mapping) and "initial_range" in curriculum):
        return env, curriculum
    curriculum = dict(curriculum)
    start = list(curriculum.pop("initial_range"))
    goal = env.get("goal") if isinstance(env, Mapping) else None
    malformed = not isinstance(env, (Mapping, type(None))) or not isinstance(goal, (Mapping, type(None)))
    if not curriculum.get("enabled", True) or malformed:
        return env, curriculum  # off: it had no effect; a malformed section gets its own error later
    goal = dict(goal or {})
    if list(goal.setdefault("radial_range", start)) != start:
        raise ValueError(
            f"curriculum.initial_range {start} differs from env.goal.radial_range "
            f"{list(goal['radial_range'])}: the goal curriculum starts from env.goal.radial_range; set it alone"
        )
    return {**(env or {}), "goal": goal}, curriculum


def _collection_key(run: dict) -> dict:
    """``run.multi_device`` as ``run.collection``."""
    old = run.pop("multi_device")
    if old not in OLD_COLLECTION:
        raise ValueError(f"config key 'run.multi_device' = {old!r}; choose one of {list(OLD_COLLECTION)}")
    if "collection" in run and run["collection"] != OLD_COLLECTION[old]:
        raise ValueError(
            f"config keys 'run.multi_device' = {old!r} and 'run.collection' = {run['collection']!r} "
            "differ: give 'run.collection' alone"
        )
    run["collection"] = OLD_COLLECTION[old]
    return run

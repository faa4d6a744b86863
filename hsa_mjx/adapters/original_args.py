"""The original ``hsa_gym`` ``HSAEnv`` constructor arguments, mapped onto this project's config.

``ORIGINAL_ARGS`` is the one table: for every keyword argument of the original's ``HSAEnv`` (and
the viewer arguments its base class took through ``**kwargs``) it names the config key(s) it sets,
how it is handled, and where this project differs from the original (the quirks it fixes,
``docs/environment.md``). ``hsa_mjx.make_env``, ``gymnasium.make("hsa_mjx/HSA-v0", ...)`` and
``gymnasium.make_vec`` accept these names beside the config keys; arguments that are not given
keep the chosen preset's values (the original's shipped flat config), not the original class
defaults (``frame_skip`` 4, ``max_increment`` 3.14, ...).

Handling: ``config`` sets the keys; ``terrain`` is one of the three coupled arguments
(``enable_terrain``, ``terrain_type``, ``goal_position``: ``terrain_settings``); ``render`` is a
viewer argument the Gymnasium adapters take themselves (``make_env``, which has no renderer,
warns and ignores it); ``only [1]`` accepts the one value that has a meaning here and refuses
others; ``warn`` accepts the argument, ignores it and says so (``OriginalArgumentWarning``).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hsa_mjx.config import TERRAIN_TYPES, EnvConfig


class OriginalArgumentWarning(UserWarning):
    """An original argument was accepted but has no effect here (the message says why)."""


@dataclasses.dataclass(frozen=True)
class OriginalArg:
    """How one original argument is handled (see the module docstring for ``handling``)."""

    keys: tuple[str, ...] = ()  # dotted config keys it sets
    handling: str = "config"  # config | terrain | render | only [1] | warn
    note: str = ""  # where the meaning differs from the original
    convert: Callable[[str, Any], tuple[Any, ...]] | None = None  # (name, value) -> one value per key


SERVO_LIMITS = {"hsaLooseModel.xml": 6.28, "hsaTerrainNoStiffModel.xml": 3141.5}
UNLOADABLE_XML = ("hsaTerrainModel.xml", "hsaModel.xml")  # the original could not load them either


def _servo_limit(name: str, value: Any) -> tuple[float]:
    """``xml_file`` -> the servo target range of that model (the only difference between the two)."""
    base = Path(str(value)).name
    if base in SERVO_LIMITS:
        return (SERVO_LIMITS[base],)
    why = " (the original could not load it either: it has no 'goal' site)" if base in UNLOADABLE_XML else ""
    raise ValueError(
        f"{name}={value!r} is not supported{why}; this project's asset stands for one of {list(SERVO_LIMITS)}"
    )


def _goal_xy(name: str, value: Any) -> tuple[str, tuple[float, float]]:
    """``goal_position`` [x, y] or [x, y, z] -> a fixed goal at (x, y)."""
    try:
        xyz = np.asarray(value, dtype=float) if np.ndim(value) == 1 else np.zeros(0)
    except (TypeError, ValueError):
        xyz = np.zeros(0)
    if xyz.shape not in ((2,), (3,)) or not np.all(np.isfinite(xyz)):
        raise ValueError(f"{name} must be a list [x, y] or [x, y, z] of finite numbers, got {value!r}")
    return "fixed", (float(xyz[0]), float(xyz[1]))


def _same(*keys: str, note: str = "") -> OriginalArg:
    return OriginalArg(keys=keys, note=note)


def _spiral(key: str) -> OriginalArg:
    """A spiral parameter: the path of the checkpoints and of the spiral terrain's track."""
    return _same(
        f"terrain.spiral.{key}", note="the spiral terrain's track follows it too (the original's track ignored it)"
    )


_VIEWER = "a setting of the original's viewer with no counterpart in this renderer"
ORIGINAL_ARGS: dict[str, OriginalArg] = {
    "xml_file": OriginalArg(
        ("control.servo_target_limit",),
        convert=_servo_limit,
        note="one asset here; the two loadable models differ only in their servo "
        "range (Loose 6.28, NoStiff 3141.5 rad); the other two are refused",
    ),
    "frame_skip": _same("control.frame_skip"),
    "max_increment": _same("control.max_increment"),
    "smooth_positions": _same("control.smooth_positions"),
    "forward_reward_weight": _same(
        "reward.forward",
        note="pays the signed velocity towards the goal; the "
        "original paid max(0, v.u) (reward__forward_rectified=True restores it)",
    ),
    "ctrl_cost_weight": _same("reward.ctrl_cost"),
    "contact_cost_weight": _same(
        "reward.contact_cost",
        note="weighs the real foot contact force above 50 N; the original's term read a torque and was always 0",
    ),
    "yvel_cost_weight": _same("reward.lateral_cost", note="subtracted as a cost; the original added it as a reward"),
    "constraint_cost_weight": _same("reward.constraint_cost"),
    "acc_cost_weight": _same("reward.acceleration_cost"),
    "joint_vel_cost_weight": _same("reward.joint_velocity_cost"),
    "distance_reward_weight": _same("reward.distance"),
    "early_termination_penalty": _same(
        "reward.termination", note="acts here; the original ignored it and always subtracted 100 (the default here)"
    ),
    "stagnation_penalty_weight": _same("reward.stagnation_cost", note="its position window is cleared at reset"),
    "alive_bonus": _same("reward.alive"),
    "checkpoint_reward": _same("reward.checkpoint"),
    "num_checkpoints": _same("goal.num_checkpoints"),
    "checkpoint_radius": _same("goal.checkpoint_radius"),
    "start_radius": _spiral("start_radius"),
    "end_radius": _spiral("end_radius"),
    "num_turns": _spiral("turns"),
    "max_episode_steps": _same(
        "termination.max_episode_steps",
        note="the env truncates there; the original "
        "left that to a TimeLimit wrapper. gymnasium.make keeps this name for its own "
        "TimeLimit; the registered entry point reads it from there and makes it the "
        "env's limit too",
    ),
    "ensure_flat_spawn": _same("terrain.flat_spawn.enabled"),
    "enable_terrain": OriginalArg(
        ("scene", "terrain_type"), "terrain", "true: the heightfield scene ('terrain'); false: the plane ('flat')"
    ),
    "terrain_type": OriginalArg(
        ("terrain_type", "goal.mode"),
        "terrain",
        "a generator name as in the original; 'spiral' also sets spiral goals (as in "
        "the original, also without terrain). A type other than flat/spiral without "
        "a heightfield: with enable_terrain=False a warning (the original drew no "
        "terrain; here the plane keeps the flat goal rule), without it an error",
    ),
    "goal_position": OriginalArg(
        ("goal.mode", "goal.position"),
        "terrain",
        note="a fixed goal at (x, y); the original overwrote it at every reset (so its "
        "goals were random); z is the marker height, ignored. Ignored with a "
        "warning when terrain_type='spiral' (the checkpoints are the goals)",
    ),
    "actuator_group": OriginalArg(
        handling="only [1]",
        note="the position servos (group 1) are the only "
        "actuators here; the torque (0) and velocity (2) groups are not modelled",
    ),
    "action_group": OriginalArg(handling="only [1]", note="actions drive the position servos (group 1)"),
    "clip_actions": OriginalArg(
        handling="warn", note="actions are always clipped to [-1, 1]; the original stored this value and never used it"
    ),
    "render_mode": OriginalArg(handling="render", note="the adapter's own render_mode"),
    "width": OriginalArg(handling="render", note="the adapter's rgb_array frame width"),
    "height": OriginalArg(handling="render", note="the adapter's rgb_array frame height"),
    "camera_name": OriginalArg(
        handling="render", note="the adapter's camera (a camera of this asset: 'track', 'overview')"
    ),
    "camera_id": OriginalArg(handling="render", note="the adapter's camera by id (-1: the free camera)"),
    "default_camera_config": OriginalArg(handling="warn", note=_VIEWER),
    "max_geom": OriginalArg(handling="warn", note=_VIEWER),
    "visual_options": OriginalArg(handling="warn", note=_VIEWER),
}
RENDER_ARGS = tuple(name for name, arg in ORIGINAL_ARGS.items() if arg.handling == "render")
CONFIG_SECTIONS = tuple(field.name for field in dataclasses.fields(EnvConfig))


def config_keys() -> list[str]:
    """Every config key in the ``section__key`` form that keyword arguments use."""

    def walk(node: Any, prefix: str) -> list[str]:
        if not dataclasses.is_dataclass(node):
            return [prefix]
        return [
            key
            for field in dataclasses.fields(node)
            for key in walk(getattr(node, field.name), f"{prefix}__{field.name}" if prefix else field.name)
        ]

    return walk(EnvConfig(), "")


def split_arguments(kwargs: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(original arguments, config overrides); anything else is a ValueError listing both kinds."""
    original = {k: v for k, v in kwargs.items() if k in ORIGINAL_ARGS}
    config = {
        k: v for k, v in kwargs.items() if k not in original and k.replace("__", ".").split(".")[0] in CONFIG_SECTIONS
    }
    unknown = sorted(set(kwargs) - set(original) - set(config))
    if unknown:
        raise ValueError(
            f"unknown argument(s) {unknown}. Accepted: the original hsa_gym HSAEnv arguments "
            f"{sorted(ORIGINAL_ARGS)}, and this project's config keys (section__key) {config_keys()}"
        )
    return original, config


def flatten(config: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Config overrides (``a__b=v``, ``a.b=v`` or ``a={"b": v}``) as dotted keys."""
    out: dict[str, Any] = {}
    for key, value in config.items():
        dotted = f"{prefix}{key.replace('__', '.')}"
        if isinstance(value, Mapping):
            out.update(flatten(value, dotted + "."))
        else:
            out[dotted] = value
    return out


def _warn(message: str) -> None:
    warnings.warn(message, OriginalArgumentWarning, stacklevel=3)


def _check_group(name: str, value: Any) -> None:
    """``actuator_group`` / ``action_group``: [1], the position servos, is the only meaningful value."""
    if isinstance(value, (list, tuple)) and list(value) == [1]:
        return
    raise ValueError(f"{name}={value!r} is not supported: only [1] has a meaning here ({ORIGINAL_ARGS[name].note})")


def _ignore(name: str, value: Any, renderer: bool) -> None:
    """Say that an accepted argument has no effect (``clip_actions=1.0`` is what happens anyway)."""
    arg = ORIGINAL_ARGS[name]
    if arg.handling == "render" and not renderer:
        _warn(
            f"{name} is ignored: make_env builds the JAX env, which has no renderer; pass it to "
            "gymnasium.make or gymnasium.make_vec"
        )
    elif arg.handling == "warn" and not (name == "clip_actions" and value == 1.0):
        _warn(f"{name}={value!r} is ignored: {arg.note}")


def terrain_settings(
    kwargs: Mapping[str, Any], base: EnvConfig, given: Mapping[str, Any]
) -> list[tuple[str, dict[str, Any]]]:
    """The coupled ``enable_terrain``, ``terrain_type`` and ``goal_position``: [(argument, {key: value})]."""
    out: list[tuple[str, dict[str, Any]]] = []
    enable, kind = kwargs.get("enable_terrain"), kwargs.get("terrain_type")
    if enable is not None:
        if not isinstance(enable, bool):
            raise ValueError(f"enable_terrain must be True or False, got {enable!r}")
        scene = {"scene": "terrain" if enable else "flat"}
        if not enable and kind is None and base.terrain_type != "flat":
            scene["terrain_type"] = "flat"  # a terrain preset without its terrain
        out.append(("enable_terrain", scene))
    heightfield = (out[0][1]["scene"] if out else given.get("scene", base.scene)) == "terrain"
    if kind is not None:
        out.append(("terrain_type", _terrain_type(kind, enable, heightfield)))
    if "goal_position" in kwargs:
        mode, xy = _goal_xy("goal_position", kwargs["goal_position"])
        if kind == "spiral":
            _warn(
                "goal_position is ignored: with terrain_type='spiral' the goals are the spiral checkpoints "
                "(the original let the spiral take precedence too)"
            )
        else:
            out.append(("goal_position", {"goal.mode": mode, "goal.position": xy}))
    return out


def _terrain_type(kind: Any, enable: bool | None, heightfield: bool) -> dict[str, Any]:
    """``terrain_type`` given the scene it lands in (see ``ORIGINAL_ARGS['terrain_type'].note``)."""
    if kind not in TERRAIN_TYPES:
        raise ValueError(f"terrain_type={kind!r} is not a terrain type; valid types: {list(TERRAIN_TYPES)}")
    goal = {"goal.mode": "spiral"} if kind == "spiral" else {}
    if heightfield or kind == "flat":
        return {"terrain_type": kind, **goal}
    if kind == "spiral":  # the original's spiral goals on the plane
        return {"terrain_type": "flat", **goal}
    if enable is False:
        _warn(
            f"terrain_type={kind!r} draws no terrain with enable_terrain=False (as in the original, which "
            "only picked its goal rule by this name); here the plane keeps the flat goal rule"
        )
        return {"terrain_type": "flat"}
    raise ValueError(
        f"terrain_type={kind!r} needs the heightfield scene: pass enable_terrain=True (the original "
        "drew no terrain with its default enable_terrain=False), or scene='terrain'"
    )


def config_from_original(
    kwargs: Mapping[str, Any], base: EnvConfig, given: Mapping[str, Any], renderer: bool = False
) -> tuple[dict[str, Any], dict[str, str]]:
    """Dotted config overrides for the original arguments, and which argument set each key.

    ``given`` holds the dotted config keys passed beside them: setting a key both ways is a
    ValueError. ``renderer``: the caller renders (viewer arguments are then not warned about).
    """
    settings: list[tuple[str, dict[str, Any]]] = []
    for name, value in kwargs.items():
        arg = ORIGINAL_ARGS[name]
        if arg.handling == "config":
            values = arg.convert(name, value) if arg.convert else (value,) * len(arg.keys)
            settings.append((name, dict(zip(arg.keys, values))))
        elif arg.handling == "only [1]":
            _check_group(name, value)
        elif arg.handling in ("render", "warn"):
            _ignore(name, value, renderer)
    settings += terrain_settings(kwargs, base, given)
    out = {key: value for _, keys in settings for key, value in keys.items()}
    source = {key: name for name, keys in settings for key in keys}
    _check_conflicts(source, given)
    return out, source


def _check_conflicts(source: Mapping[str, str], given: Mapping[str, Any]) -> None:
    """An original argument and a config key may not set the same key."""
    for key, name in source.items():
        for other in given:
            if other == key or other.startswith(key + ".") or key.startswith(other + "."):
                raise ValueError(
                    f"the original argument {name} and the config key {other.replace('.', '__')} "
                    f"both set '{key}'; pass only one of them"
                )


def build_config(
    name_or_config: str | Path | EnvConfig = "flat", renderer: bool = False, **overrides: Any
) -> EnvConfig:
    """The :class:`EnvConfig` that ``make_env`` builds its env from (same arguments; nothing compiled).

    ``renderer``: the caller renders, so the original's viewer arguments are not warned about.
    """
    from hsa_mjx.config import get_preset, load_config, with_overrides

    if isinstance(name_or_config, EnvConfig):
        config = name_or_config
    elif isinstance(name_or_config, Path) or str(name_or_config).endswith((".yaml", ".yml")):
        config = load_config(name_or_config)
    elif isinstance(name_or_config, str):
        config = get_preset(name_or_config)
    else:
        raise ValueError(f"make_env expects a preset name, a YAML path or an EnvConfig, got {name_or_config!r}")
    original, keys = split_arguments(overrides)
    given = flatten(keys)
    mapped, source = config_from_original(original, config, given, renderer)
    if not (given or mapped):
        return config
    try:
        return with_overrides(config, **given, **mapped)
    except ValueError as err:  # name the original argument behind a refused key
        named = [
            f"'{key}' comes from the original argument {name}={original[name]!r}"
            for key, name in source.items()
            if f"'{key}'" in str(err)
        ]
        raise ValueError("; ".join([str(err), *named])) from None

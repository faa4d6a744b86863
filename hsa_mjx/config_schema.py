"""Config dataclasses from and to plain mappings: the key and type checks every config section shares.

A config is a frozen tree of dataclasses with annotated fields (bool, int, float, str, tuples of
them, nested sections). ``build_section`` maps YAML data onto one, refusing unknown keys and wrong
types with a ``ValueError`` that names the dotted key; ``plain`` turns one back into YAML-ready data.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from typing import Any


def coerce(value: Any, annotation: Any, key: str) -> Any:
    """Convert a YAML value to the annotated type or raise ValueError naming the key."""
    origin = typing.get_origin(annotation)
    if annotation is bool:
        if not isinstance(value, bool):
            raise ValueError(f"config key '{key}' must be true or false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"config key '{key}' must be an integer, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"config key '{key}' must be a number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ValueError(f"config key '{key}' must be a string, got {value!r}")
        return value
    if origin is tuple:
        args = typing.get_args(annotation)
        if len(args) == 2 and args[1] is Ellipsis:  # tuple[T, ...]: any length >= 1
            if not isinstance(value, (list, tuple)) or not value:
                raise ValueError(f"config key '{key}' must be a non-empty list, got {value!r}")
            return tuple(coerce(v, args[0], key) for v in value)
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise ValueError(f"config key '{key}' must be a list of {len(args)} numbers, got {value!r}")
        return tuple(coerce(v, a, key) for v, a in zip(value, args))
    raise TypeError(f"unsupported annotation {annotation!r} for '{key}'")  # programming error


def build_section(cls: type, data: Mapping[str, Any], prefix: str = "") -> Any:
    """Build config dataclass ``cls`` from a mapping, recursing into nested sections: unknown keys and
    wrong types raise ValueError naming the key; the dataclass checks its own values as it is built."""
    if not isinstance(data, Mapping):
        raise ValueError(f"config section '{prefix or '<root>'}' must be a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        where = f"section '{prefix}'" if prefix else "the top level"
        raise ValueError(f"unknown config key(s) {unknown} in {where}; valid keys: {sorted(fields)}")
    kwargs = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        hint = hints[name]
        if dataclasses.is_dataclass(hint):
            kwargs[name] = build_section(hint, value, key)
        elif fields[name].default == () and isinstance(value, (list, tuple)) and not value:
            kwargs[name] = ()  # a list whose default is empty may be empty
        else:
            kwargs[name] = coerce(value, hint, key)
    return cls(**kwargs)


def non_finite(config: Any, prefix: str = "") -> list[str]:
    """Dotted keys of every NaN or infinite number in a config tree."""
    bad = []
    for field in dataclasses.fields(config):
        value, key = getattr(config, field.name), f"{prefix}{field.name}"
        if dataclasses.is_dataclass(value):
            bad += non_finite(value, key + ".")
        elif any(
            isinstance(v, float) and not math.isfinite(v) for v in (value if isinstance(value, tuple) else (value,))
        ):
            bad.append(f"'{key}' = {value!r}")
    return bad


def plain(config: Any) -> dict:
    """A config dataclass as plain nested dicts and lists (tuples become lists)."""

    def convert(value: Any) -> Any:
        if isinstance(value, tuple):
            return [convert(v) for v in value]
        if isinstance(value, dict):
            return {k: convert(v) for k, v in value.items()}
        return value

    return convert(dataclasses.asdict(config))

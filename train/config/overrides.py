"""``--set section.key=value`` overrides of a training config's nested data (values parsed as YAML),
re-exported by ``train.config``."""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from typing import Any

import yaml

from hsa_mjx import migrations

SECTIONS = ("env", "goal_curriculum", "terrain_curriculum", "randomization_curriculum", "ppo", "td3", "run")


def apply_overrides(data: dict, assignments: list[str]) -> dict:
    """Apply ``section.key=value`` strings (values parsed as YAML) to nested config data (its older keys
    mapped first, so that an override and the file's key meet under one name); ``data`` is left as it is."""
    data = copy.deepcopy(dict(migrations.training_keys(data)))
    for item in assignments:
        dotted, value = parse_assignment(item)
        parts = dotted.split(".")
        parts[0] = migrations.SECTION_NAMES.get(parts[0], parts[0])
        if len(parts) < 2 or parts[0] not in SECTIONS:
            raise ValueError(
                f"--set key {dotted!r} must start with one of {list(SECTIONS)}, e.g. ppo.learning_rate=1e-4"
            )
        node = data.setdefault(parts[0], {})
        for part in parts[1:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return data


def parse_assignment(item: str) -> tuple[str, Any]:
    """(dotted key, value) of one ``section.key=value`` string, the value parsed as YAML."""
    if "=" not in item:
        raise ValueError(f"--set expects section.key=value, got {item!r}")
    dotted, raw = item.split("=", 1)
    return dotted.strip(), _parse_value(raw)


def assignments(values: Mapping[str, Any]) -> list[str]:
    """``section.key=value`` strings of a mapping of dotted keys to values (:func:`apply_overrides`'s input)."""
    return [f"{key}={json.dumps(value)}" for key, value in values.items()]


def _parse_value(raw: str) -> Any:
    """A --set value as YAML, with numbers like ``2e-4`` (YAML 1.1 reads them as strings) as floats."""
    value = yaml.safe_load(raw)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value

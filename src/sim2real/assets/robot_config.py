"""configs/{robot}/robot.yaml: read against its schema, and its joint patterns (``armature``, ``home``,
``actuators``: a joint name or glob -> value, the first matching pattern wins)."""

from __future__ import annotations

import fnmatch
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sim2real.files import read_validated_yaml, validate

ROBOT_SCHEMA = "robot.schema.yaml"


def read_robot_config(path: str | Path, settings: Mapping[str, Any] | None = None) -> Any:
    """robot.yaml, validated against ``schemas/robot.schema.yaml`` (an error names the file, the key and the fix).
    ``settings``: its content as already read (the DAG passes a stage the part it reads as params), validated the
    same and named by ``path`` in an error."""
    if settings is not None:
        return validate(dict(settings), ROBOT_SCHEMA, path)
    return read_validated_yaml(path, ROBOT_SCHEMA)


def first_match(name: str, patterns: Mapping[str, Any]) -> Any | None:
    """The value of the first pattern (a name or a glob) that ``name`` matches, None when none does."""
    for pattern, value in patterns.items():
        if fnmatch.fnmatchcase(name, pattern):
            return value
    return None

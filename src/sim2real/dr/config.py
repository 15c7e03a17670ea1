"""The ``configs/{robot}/dr.yaml`` checks that need no model: the schema, friendlier errors for
template keys MuJoCo cannot represent, and per term the mode, range order, distribution and the
physical bounds of the declared (scale / abs) values, plus the curriculum levels.

Every error is an :class:`InputError` naming the key path and the fix. The checks against the built
MJCF (selectors, nominal values, absolute ranges) are in :mod:`sim2real.dr.resolve`, which calls
these term by term, so the first error reported is the same as if it were one pass.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.dr.parameters import NOISE_TERMS, Parameter, bound_words, fmt, is_physical
from sim2real.errors import InputError
from sim2real.files import validate

SCHEMA_NAME = "dr.schema.json"
PHYSICS_MODES = ("startup", "reset")


def validate_config(config: Any, path: str | Path | None) -> None:
    """Template keys MuJoCo cannot represent, then the schema."""
    _preschema_checks(config, path)
    validate(config, SCHEMA_NAME, path)


def _preschema_checks(config: Any, path: str | Path | None) -> None:
    """Friendlier errors than the schema would give for template keys MuJoCo cannot represent."""
    if not isinstance(config, Mapping):
        return
    physics = config.get("physics_randomization")
    friction = physics.get("surface_friction") if isinstance(physics, Mapping) else None  # else the schema says why
    if isinstance(friction, Mapping):
        for key in ("static_friction_range", "dynamic_friction_range", "restitution_range"):
            if key in friction:
                raise InputError(
                    path,
                    f"key 'physics_randomization/surface_friction/{key}'",
                    "MuJoCo has a single Coulomb (sliding) friction coefficient per geom and no restitution coefficient",
                    "replace the static/dynamic/restitution ranges by one 'range: [low, high]' for the sliding friction",
                )


def _check_range(lo_hi: Sequence[float], path: str | Path | None, key: str) -> tuple[float, float]:
    lo, hi = float(lo_hi[0]), float(lo_hi[1])
    if lo > hi:
        raise InputError(path, f"key '{key}'", f"range [{fmt(lo)}, {fmt(hi)}] is reversed", f"write it as [{fmt(hi)}, {fmt(lo)}]")
    if lo == hi:
        raise InputError(
            path,
            f"key '{key}'",
            f"range [{fmt(lo)}, {fmt(hi)}] is empty (zero width), it randomizes nothing",
            "widen it to [low, high] with low < high, or remove the term",
        )
    return lo, hi


@dataclass(frozen=True)
class DeclaredTerm:
    """One physics channel as dr.yaml declares it (declared space, seconds for a delay)."""

    key: str  # physics_randomization/<term>
    range_key: str  # key path of its range
    mode: str
    distribution: str
    operation: str
    lo: float
    hi: float
    mean: float | None
    std: float | None


def declared_physics(term_cfg: Mapping[str, Any], parameter: Parameter, path: str | Path | None) -> DeclaredTerm:
    """Check one physics channel of dr.yaml on its own (no model needed)."""
    base_key = f"physics_randomization/{parameter.term}"
    mode = term_cfg["mode"]
    if mode not in PHYSICS_MODES:
        raise InputError(
            path,
            f"key '{base_key}/mode'",
            f"physics parameter '{parameter.term}' is randomized at '{mode}': a model parameter that changes every "
            "step is not a physical robot and breaks the integrator's assumptions",
            "use 'mode: reset' (one draw per episode) or 'mode: startup' (one draw per sampler)",
        )
    operation = term_cfg.get("operation", parameter.default_operation)
    distribution = term_cfg["distribution"]
    range_key = f"{base_key}/{parameter.range_key}"
    unit_factor = 1e-3 if term_cfg.get("unit") == "milliseconds" else 1.0

    raw_range = term_cfg.get(parameter.range_key)
    if raw_range is None:
        # Only gaussian without a truncation range can get here (schema requires ranges otherwise).
        raise InputError(
            path,
            f"key '{base_key}'",
            f"gaussian '{parameter.term}' has no '{parameter.range_key}' to bound it, so it could draw non-physical values",
            f"add '{parameter.range_key}: [low, high]' as the truncation interval",
        )
    lo, hi = _check_range([v * unit_factor for v in raw_range], path, range_key)
    mean = std = None
    if distribution == "gaussian":
        mean = float(term_cfg["mean"]) * unit_factor
        std = float(term_cfg["std"]) * unit_factor
        if not lo <= mean <= hi:
            raise InputError(
                path,
                f"key '{base_key}/mean'",
                f"mean {fmt(mean)} lies outside the truncation range [{fmt(lo)}, {fmt(hi)}]",
                "move the mean inside the range or widen the range",
            )
    if distribution == "log_uniform" and lo <= 0:
        raise InputError(
            path,
            f"key '{range_key}'",
            f"log_uniform needs a positive range, got [{fmt(lo)}, {fmt(hi)}]",
            "use a range with low > 0, or distribution 'uniform'",
        )
    # Declared-space physical checks (independent of the model).
    if operation == "scale" and parameter.lower_bound is not None:
        if lo < 0 or (parameter.strict and lo == 0):
            raise InputError(
                path,
                f"key '{range_key}'",
                f"a {parameter.quantity} scale of {fmt(lo)} is not physical (scale must be {'> 0' if parameter.strict else '>= 0'})",
                f"use a lower bound {'> 0' if parameter.strict else '>= 0'}, e.g. [{fmt(max(0.5, lo))}, {fmt(max(hi, 1.5))}]",
            )
    if operation == "abs" and not is_physical(lo, parameter):
        raise InputError(
            path,
            f"key '{range_key}'",
            f"a {parameter.quantity} of {fmt(lo)} {parameter.unit} is not physical (must be {bound_words(parameter)})",
            f"raise the lower bound to {bound_words(parameter)}",
        )
    return DeclaredTerm(base_key, range_key, mode, distribution, operation, lo, hi, mean, std)


def declared_noise(name: str, term_cfg: Mapping[str, Any], path: str | Path | None) -> dict[str, Any]:
    """Check one observation-noise term of dr.yaml; its dr.json entry without the targets."""
    noise = NOISE_TERMS[name]
    base_key = f"observation_noise/{name}"
    mode = term_cfg["mode"]
    if mode != "step":
        raise InputError(
            path,
            f"key '{base_key}/mode'",
            f"observation noise '{name}' is drawn at '{mode}': one draw held for a whole episode is a sensor bias, "
            "not noise, and the policy learns to cancel it",
            "use 'mode: step' (a fresh draw at every observation)",
        )
    distribution = term_cfg["distribution"]
    resolved: dict[str, Any] = {"term": name, "element": noise.element, "unit": noise.unit, "mode": mode,
                                "distribution": distribution}
    if distribution == "gaussian":
        resolved["mean"] = float(term_cfg.get("mean", 0.0))
        resolved["std"] = float(term_cfg["std"])
    else:
        resolved["range"] = list(_check_range(term_cfg["range"], path, f"{base_key}/range"))
    return resolved


def curriculum_levels(config: Mapping[str, Any], path: str | Path | None) -> dict[str, Any]:
    curriculum = config.get("curriculum")
    if not curriculum:
        return {"levels": [{"name": "full", "scale": 1.0}], "default_level": "full"}
    levels = [{"name": str(level["name"]), "scale": float(level["scale"])} for level in curriculum["levels"]]
    names = [level["name"] for level in levels]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise InputError(path, "key 'curriculum/levels'", f"level names repeat: {', '.join(duplicates)}", "give each level a unique name")
    default_level = curriculum.get("default_level", names[-1])
    if default_level not in names:
        raise InputError(
            path,
            "key 'curriculum/default_level'",
            f"'{default_level}' is not a level",
            f"use one of: {', '.join(names)}",
        )
    return {"levels": levels, "default_level": default_level}

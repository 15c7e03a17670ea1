"""``configs/{robot}/model.yaml``, the model ladder, parsed and validated once (:func:`load_model_config`): the rules
(:mod:`sim2real.workflow.configs`), the identification and the excitation design all read it through here.

The file (``schemas/model.schema.yaml``): ``effects``, the ladder's lines in order, each an effect's name or, for a
drive effect kept on one side of the comparison, ``{name: side}`` (``- asymmetric_friction: actuator``), or, for an
effect whose parameters are per joint, ``{name: {joints: [...], side: ...}}`` (``- coulomb_friction: {joints:
[panda_joint1, panda_joint3]}``: fitted on those joints only, absent on the others); ``fit``, the
fit settings; ``diagnosis``, when the diagnosis names an effect. A setting left out is None here: its default
applies (``sim2real.identification.fitting.DEFAULT_SETTINGS``, ``sim2real.identification.diagnosis.DEFAULT_DIAGNOSIS``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from sim2real.identification.records import Side
from sim2real.errors import InputError

# The sides a drive effect's line may keep it on (sim2real.identification.sides), as model.yaml writes them (the
# values of the sides' enum once the identification names them: body, and the drive's "actuator").
# The sides a drive line may be kept on (the documents' words, ``- asymmetric_friction: actuator``).
LINE_SIDES: tuple[Side, ...] = (Side.BODY, Side.DRIVE)


# The fit setting that holds the lines kept on some joints ({effect: [joints]}; absent when no line is):
# sim2real.identification.fitting.EFFECT_JOINTS_SETTING names the same key.
EFFECT_JOINTS_KEY = "effect_joints"


@dataclass(frozen=True)
class EffectLine:
    """A line of model.yaml's ``effects``: the effect, the side it is kept on (None: every side it belongs to) and
    the joints it is kept on (None: every joint)."""

    name: str
    side: Side | None = None
    joints: tuple[str, ...] | None = None


@dataclass(frozen=True)
class FitSettings:
    """model.yaml's ``fit`` (the schema describes each); None: not given, the default applies."""

    fit_rate_hz: float | None = None
    refine_max_samples: int | None = None
    refine_windows_s: float | None = None
    bootstrap_replicates: int | None = None
    bootstrap_block_s: float | None = None
    confidence: float | None = None
    seed: int | None = None
    inertia_regularization: float | Literal["held_out"] | None = None
    joint_weighting: Literal["noise_floor", "none"] | None = None


@dataclass(frozen=True)
class DiagnosisSettings:
    """model.yaml's ``diagnosis`` (the schema describes each); None: not given, the default applies."""

    min_explained: float | None = None
    joint_min_explained: float | None = None
    noise_floor_factor: float | None = None


@dataclass(frozen=True)
class ModelConfig:
    """model.yaml, validated: the ladder's lines, the fit and diagnosis settings, and the file they came from."""

    lines: tuple[EffectLine, ...] = ()
    fit: FitSettings = field(default_factory=FitSettings)
    diagnosis: DiagnosisSettings = field(default_factory=DiagnosisSettings)
    path: Path | None = field(default=None, compare=False)

    @property
    def effects(self) -> tuple[str, ...]:
        """The ladder's effects in order (empty: the nominal model only)."""
        return tuple(line.name for line in self.lines)

    @property
    def sides(self) -> dict[str, Side]:
        """The effects kept on one side: {effect: side}."""
        return {line.name: line.side for line in self.lines if line.side is not None}

    @property
    def joints(self) -> dict[str, tuple[str, ...]]:
        """The effects kept on some joints: {effect: joints}."""
        return {line.name: line.joints for line in self.lines if line.joints is not None}

    def as_settings(self) -> dict[str, Any]:
        """The settings mapping :func:`sim2real.identification.sysid.fit_model` reads: ``effects``, ``links`` (the
        effects kept on one side), and the ``fit`` settings given (with :data:`EFFECT_JOINTS_KEY`, the lines kept on
        some joints, when any is) and the ``diagnosis`` settings given."""
        fit = _given(self.fit)
        if self.joints:
            fit[EFFECT_JOINTS_KEY] = {name: list(joints) for name, joints in self.joints.items()}
        return {"effects": list(self.effects), "links": {k: str(v) for k, v in self.sides.items()}, "fit": fit,
                "diagnosis": _given(self.diagnosis)}

    def check_joints(self, joint_names: Sequence[str]) -> None:
        """Refuse a line kept on a joint the runs do not hold (``joint_names``: the identified joints)."""
        for i, line in enumerate(self.lines):
            unknown = [j for j in line.joints or () if j not in joint_names]
            if unknown:
                raise InputError(self.path, f"effects/{i}", f"'{line.name}' is kept on {', '.join(unknown)}, "
                                 "which no run of this robot holds", f"name joints among: {', '.join(joint_names)}")


def _given(section: FitSettings | DiagnosisSettings) -> dict[str, Any]:
    values = {f.name: getattr(section, f.name) for f in dataclasses.fields(section)}
    return {name: value for name, value in values.items() if value is not None}


def load_model_config(path: str | Path) -> ModelConfig:
    """configs/{robot}/model.yaml read and validated (:func:`parse_model_config`); ``InputError`` names the file, the
    line and the fix."""
    from sim2real.files import read_validated_yaml

    return parse_model_config(read_validated_yaml(path, "model.schema.yaml"), path)


def parse_model_config(data: Mapping[str, Any] | None, path: str | Path) -> ModelConfig:
    """model.yaml's content (``data``, valid against its schema; None: an empty file) of the file ``path``."""
    data = data or {}
    return ModelConfig(effect_lines(data.get("effects") or [], path), FitSettings(**(data.get("fit") or {})),
                       DiagnosisSettings(**(data.get("diagnosis") or {})), Path(path))


def effect_lines(lines: Sequence[str | Mapping[str, Any]], path: str | Path) -> tuple[EffectLine, ...]:
    """The lines of model.yaml's ``effects`` (of the file ``path``, named in an error): each a known effect, listed
    once, or ``{effect: side}``, a drive effect kept on one side (behind a link-side sensor a drive's effect is
    fitted on both sides; a user whose other side it leaves worse, as the verdict says, keeps it on one), or
    ``{effect: {joints: [...], side: ...}}``, an effect whose parameters are per joint kept on those joints (one the
    verdict says the effect raises is kept off)."""
    from sim2real.identification.effects import get_effect

    names = [next(iter(line)) if isinstance(line, Mapping) and len(line) == 1 else line for line in lines]
    seen = set()
    for i, name in enumerate(names):
        if not isinstance(name, str):
            raise InputError(path, f"effects/{i}", f"'{lines[i]}' is no effect's line",
                             "write '- <effect>', or '- <effect>: actuator' for a drive effect kept on one side")
        get_effect(name, str(path))
        if name in seen:
            raise InputError(path, f"effects/{i}", f"'{name}' is listed twice", "list each effect once")
        seen.add(name)
    return tuple(_effect_line(i, name, line, path) for i, (name, line) in enumerate(zip(names, lines, strict=True)))


def _effect_line(i: int, name: str, line: str | Mapping[str, Any], path: str | Path) -> EffectLine:
    """The line ``i`` of ``effects`` (the effect ``name``, known), its side and joints checked."""
    from sim2real.identification.effects import get_effect

    if not isinstance(line, Mapping):
        return EffectLine(name)
    value = line[name]
    options = value if isinstance(value, Mapping) else {"side": value}
    side, joints = options.get("side"), options.get("joints")
    if side is not None and side not in LINE_SIDES:
        raise InputError(path, f"effects/{i}", f"'{name}: {side}' names no side",
                         f"write '- {name}: actuator' or '- {name}: body'")
    if side is not None and not get_effect(name, str(path)).drive:
        raise InputError(path, f"effects/{i}", f"'{name}' is fitted on one side only: there is no other side to "
                         "keep it off", f"write '- {name}'")
    if joints is not None and not get_effect(name, str(path)).per_joint_line:
        raise InputError(path, f"effects/{i}", f"'{name}' cannot be kept on some joints: its parameters act on "
                         "every joint together (or on none alone)", f"write '- {name}', without joints")
    if joints is not None and (not joints or len(set(joints)) != len(joints)):
        raise InputError(path, f"effects/{i}", f"'{name}: {{joints: {list(joints)}}}' lists no joint, or one twice",
                         f"list each joint once, e.g. '- {name}: {{joints: [<joint>]}}', or write '- {name}'")
    return EffectLine(name, Side(side) if side is not None else None,
                      tuple(joints) if joints is not None else None)

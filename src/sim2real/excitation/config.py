"""``configs/{robot}/excitation.yaml``: the designs, validated, with the checks a schema cannot make.

The checks that need the robot (limits that leave no motion, a start pose outside them) live here too,
so that every error names the excitation file, the key and the fix.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.files import merge_settings, read_validated_yaml

DEFAULTS: dict[str, Any] = {
    "duration_s": 20.0,
    "base_frequency_hz": 0.1,
    "harmonics": 5,
    "sample_rate_hz": 1000.0,
    "trajectory_rate_hz": 100.0,
    "start": "home",
    "acceleration_limit": 10.0,
    "margins": {"position_rad": 0.1, "velocity_fraction": 0.3, "acceleration_fraction": 0.3,
                "torque_fraction": 0.3, "collision_m": 0.02},
    "obstacles": [],
    "objective": "d_optimal",
    "noise_floor": None,
    "solver": {"max_iterations": 120, "objective_samples": 120, "limit_samples": 400, "seed": 0},
}
PERIOD_TOLERANCE = 1e-6  # relative: a duration this close to a whole number of periods is one
INERTIAL_EFFECTS = ("link_inertia", "payload")  # their columns are (combinations of) the inertial ones
DEFAULT_FRICTION = ("viscous_friction", "coulomb_friction")


def identification_effects(model_effects: Sequence[str]) -> list[str]:
    """The effects whose columns the design must make identifiable (model order, friction added if absent): the
    DAG passes these to a design as its param, so a line of model.yaml that adds no column (a payload, a delay)
    or none a design can aim at (a position ripple, whose period no design knows: :attr:`Effect.in_design`) reruns no
    design. ``model_effects``: model.yaml's effects (:attr:`sim2real.identification.model_config.ModelConfig.effects`;
    a drive effect kept on one side is designed for as any other)."""
    from sim2real.identification.effects import EFFECTS

    names = [e for e in model_effects if e in EFFECTS and e not in INERTIAL_EFFECTS and not EFFECTS[e].time_shift
             and EFFECTS[e].in_design]
    if not any("friction" in e for e in names):
        names += [e for e in DEFAULT_FRICTION if e not in names]
    return names


@dataclass(frozen=True)
class Limits:
    """The motion a design may use, per joint (all arrays in ``joints`` order), margins applied."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    torque: np.ndarray


@dataclass(frozen=True)
class Design:
    """One design of the file, merged with its defaults and checked."""

    name: str
    path: Path
    joints: list[str]
    excite: list[str]
    settings: dict[str, Any]

    def key(self, *parts: str) -> str:
        return "/".join(("designs", self.name, *parts))

    def spec(self) -> dict[str, Any]:
        """What the design reads of its file, as plain data: the DAG passes it to the design's jobs as a param, so a
        comment or another design's entry reruns no design (:func:`design_from_spec` gives the design back)."""
        return {"joints": list(self.joints), "excite": list(self.excite), "settings": self.settings}

    @property
    def periods(self) -> int:
        return int(round(self.settings["duration_s"] * self.settings["base_frequency_hz"]))

    def per_joint(self, key: str) -> np.ndarray | None:
        """A per-joint setting (scalar, list in ``joints`` order or {joint: value}) as an array, or None."""
        value = self.settings.get(key)
        if value is None:
            return None
        if isinstance(value, Mapping):
            unknown = [k for k in value if k not in self.joints]
            if unknown:
                raise InputError(self.path, self.key(key), f"unknown joint(s) {', '.join(unknown)}",
                                 f"use joints of `joints`: {', '.join(self.joints)}")
            missing = [j for j in self.joints if j not in value]
            if missing:
                raise InputError(self.path, self.key(key), f"no value for {', '.join(missing)}",
                                 "give every joint a value, or one scalar for all")
            return np.array([float(value[j]) for j in self.joints])
        if isinstance(value, Sequence):
            if len(value) != len(self.joints):
                raise InputError(self.path, self.key(key), f"has {len(value)} values for {len(self.joints)} joints",
                                 "give one value per joint in `joints` order, a scalar, or a {joint: value} map")
            return np.asarray(value, dtype=float)
        return np.full(len(self.joints), float(value))


def load_designs(path: str | Path) -> dict[str, Design]:
    """Every design of the file, defaults merged, with the checks that need no robot."""
    path = Path(path)
    data = read_validated_yaml(path, "excitation.schema.yaml")
    joints = list(data["joints"])
    if len(set(joints)) != len(joints):
        raise InputError(path, "joints", "a joint is listed twice", "list each joint once")
    base = merge_settings(DEFAULTS, data.get("defaults") or {})
    designs = {}
    for name, spec in data["designs"].items():
        design = Design(name, path, joints, [], merge_settings(base, spec or {}))
        excite = list(design.settings.get("excite") or joints)
        unknown = [j for j in excite if j not in joints]
        if unknown:
            raise InputError(path, design.key("excite"), f"unknown joint(s) {', '.join(unknown)}",
                             f"excite joints of `joints`: {', '.join(joints)}")
        design = Design(name, path, joints, [j for j in joints if j in excite], design.settings)
        _check_period(design)
        designs[name] = design
    return designs


def design_from_spec(path: str | Path, name: str, spec: Mapping[str, Any]) -> Design:
    """The design ``name`` of the file ``path`` from its :meth:`Design.spec` (already checked when it was read)."""
    return Design(name, Path(path), list(spec["joints"]), list(spec["excite"]), dict(spec["settings"]))


def load_design(path: str | Path, name: str, allow_default: bool = False) -> Design:
    """One design; ``allow_default``: a name the file does not list takes the defaults (a separating run)."""
    designs = load_designs(path)
    if name not in designs and allow_default:
        data = read_validated_yaml(Path(path), "excitation.schema.yaml")
        joints = list(data["joints"])
        design = Design(name, Path(path), joints, [], merge_settings(DEFAULTS, data.get("defaults") or {}))
        design = Design(name, Path(path), joints, list(design.settings.get("excite") or joints), design.settings)
        _check_period(design)
        return design
    if name not in designs:
        raise InputError(path, f"designs/{name}", "no such design", f"add it under `designs:` or use one of "
                         f"{', '.join(sorted(designs))}")
    return designs[name]


def _check_period(design: Design) -> None:
    settings = design.settings
    duration, frequency = float(settings["duration_s"]), float(settings["base_frequency_hz"])
    period = 1.0 / frequency
    if duration < period * (1.0 - PERIOD_TOLERANCE):
        raise InputError(
            design.path, design.key("duration_s"),
            f"{duration:g} s is shorter than one period of the base frequency ({period:g} s at {frequency:g} Hz)",
            f"make duration_s at least {period:g} s, or raise base_frequency_hz to at least {1.0 / duration:.4g}",
        )
    periods = duration * frequency
    if abs(periods - round(periods)) > PERIOD_TOLERANCE * periods:
        whole = max(1, int(round(periods)))
        raise InputError(
            design.path, design.key("duration_s"),
            f"{duration:g} s is {periods:.4g} periods of the base frequency: the trajectory would not end at rest "
            "at the start pose",
            f"use duration_s {whole / frequency:g} ({whole} periods) or base_frequency_hz {whole / duration:.6g}",
        )
    rate = float(settings["sample_rate_hz"])
    if abs(duration * rate - round(duration * rate)) > 1e-6:
        raise InputError(design.path, design.key("sample_rate_hz"), "the duration is not a whole number of samples",
                         "choose sample_rate_hz so that duration_s * sample_rate_hz is an integer")
    harmonics = int(settings["harmonics"])
    if harmonics * frequency >= rate / 2:
        raise InputError(design.path, design.key("harmonics"),
                         f"the highest harmonic ({harmonics * frequency:g} Hz) is above the Nyquist rate of the samples",
                         "use fewer harmonics or a higher sample_rate_hz")


def start_pose(design: Design, home: Mapping[str, float], lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """The start pose in ``joints`` order: robot.yaml's home or the design's map (0 clipped for joints not in it)."""
    start = design.settings["start"]
    values = dict(home) if start == "home" else dict(start)
    if start != "home":
        unknown = [k for k in values if k not in design.joints]
        if unknown:
            raise InputError(design.path, design.key("start"), f"unknown joint(s) {', '.join(unknown)}",
                             f"use joints of `joints`: {', '.join(design.joints)}")
    return np.clip(np.array([float(values.get(j, 0.0)) for j in design.joints]), lower, upper)


def limits(design: Design, lower: np.ndarray, upper: np.ndarray, velocity: np.ndarray, effort: np.ndarray,
           start: np.ndarray, gravity_at_start: np.ndarray, urdf: str | Path) -> Limits:
    """Limits with margins; errors where they leave no feasible motion or exclude the start pose."""
    margins = design.settings["margins"]
    acceleration = design.per_joint("acceleration_limit")
    assert acceleration is not None  # defaulted
    for label, values in (("velocity", velocity), ("effort", effort)):
        bad = [j for j, v in zip(design.joints, values, strict=True) if not np.isfinite(v) or v <= 0]
        if bad:
            raise InputError(urdf, f"joint(s) {', '.join(bad)}", f"no positive {label} limit",
                             f"give each identified joint <limit {label}=...> in the Xacro")
    m = float(margins["position_rad"])
    lo, hi = lower + m, upper - m
    for j, name in enumerate(design.joints):
        if name not in design.excite:
            continue
        if hi[j] <= lo[j]:
            raise InputError(
                design.path, design.key("margins", "position_rad"),
                f"a margin of {m:g} rad leaves {name} no feasible motion (its range is {upper[j] - lower[j]:.3g} rad)",
                f"use a margin below {0.5 * (upper[j] - lower[j]):.3g} rad or do not excite {name}",
            )
        if not lo[j] <= start[j] <= hi[j]:
            raise InputError(
                design.path, design.key("start"),
                f"{name} starts at {start[j]:.4g} rad, within {m:g} rad of its limits [{lower[j]:.4g}, {upper[j]:.4g}]",
                "move the start pose inside the limits minus the position margin, or lower margins/position_rad",
            )
    torque = (1.0 - float(margins["torque_fraction"])) * effort
    over = [j for j in range(len(design.joints)) if abs(gravity_at_start[j]) >= torque[j]]
    if over:
        j = over[0]
        raise InputError(
            design.path, design.key("margins", "torque_fraction"),
            f"holding the start pose already takes {abs(gravity_at_start[j]):.3g} N*m on {design.joints[j]}, above "
            f"its usable torque {torque[j]:.3g} N*m: no motion is feasible",
            "lower margins/torque_fraction or choose a start pose nearer to the upright",
        )
    return Limits(lower=lo, upper=hi, velocity=(1.0 - float(margins["velocity_fraction"])) * velocity,
                  acceleration=(1.0 - float(margins["acceleration_fraction"])) * acceleration, torque=torque)

"""Hidden effects that act as torques along the motion or on the sensor: Gaz's friction, Stribeck humps, Dahl's
friction with memory, a friction that grows with the load, cogging, a warm-up drift. The lab implements them itself: it never imports the fit's effects."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.lab.config import _per_joint


def gaz_friction(qd: np.ndarray, phi1: np.ndarray, phi2: np.ndarray, phi3: np.ndarray) -> np.ndarray:
    """Friction torque of Gaz et al. 2019 (zero at rest), per joint."""
    return phi1 / (1.0 + np.exp(-phi2 * (qd + phi3))) - phi1 / (1.0 + np.exp(-phi2 * phi3))


# The hump's sign is tanh(qd / this): near a true sign, yet smooth enough for the explicit passive torque at 1 kHz
# with peaks of a few tenths of N*m (slope peak/0.005 N*m*s/rad at rest).
STRIBECK_SMOOTHING_RAD_S = 0.005


def stribeck_friction(qd: np.ndarray, peak: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Stribeck hump, along the velocity: peak * exp(-(qd/velocity)^2) * tanh(qd/0.005), per joint."""
    return peak * np.exp(-((qd / velocity) ** 2)) * np.tanh(qd / STRIBECK_SMOOTHING_RAD_S)


def _joint_friction(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                    truth: dict[str, Any]) -> dict[str, Any]:
    """``coulomb_friction``'s passive torques (Gaz sigmoid, Stribeck hump) and its ``after_sensor`` fraction.

    Returns ``{gaz, stribeck, after}`` (None, None, zeros when absent) and records the hidden values in
    ``truth["coulomb_friction"]`` (the ``sign`` model's coefficient is already there, from the spec).
    """
    n = len(joints)
    friction: dict[str, Any] = {"gaz": None, "stribeck": None, "after": np.zeros(n)}
    coulomb = effects.get("coulomb_friction")
    if not coulomb:
        return friction
    where = "coulomb_friction"
    if coulomb.get("model") == "gaz_sigmoid":
        friction["gaz"] = tuple(_per_joint(coulomb[k], joints, f"{where}/{k}", path) for k in ("phi1", "phi2", "phi3"))
        truth[where] = {"model": "gaz_sigmoid",
                        **{k: dict(zip(joints, v.tolist())) for k, v in zip(("phi1", "phi2", "phi3"), friction["gaz"])}}
    record = truth.setdefault(where, {})
    if "stribeck" in coulomb:
        hump = coulomb["stribeck"]
        if not isinstance(hump, Mapping) or not {"peak", "velocity"} <= set(hump):
            raise InputError(path, f"{where}/stribeck", "needs peak and velocity", "give {peak: N*m, velocity: rad/s}")
        peak = _per_joint(hump["peak"], joints, f"{where}/stribeck/peak", path)
        velocity = _per_joint(hump["velocity"], joints, f"{where}/stribeck/velocity", path)
        if not np.all(np.isfinite(peak)) or np.any(peak < 0):
            raise InputError(path, f"{where}/stribeck/peak", "a peak is negative or not finite", "give peaks >= 0 N*m")
        if np.any((peak > 0) & ~(velocity > 0)) or not np.all(np.isfinite(velocity)):
            raise InputError(path, f"{where}/stribeck/velocity", "a joint with a peak has no positive velocity",
                             "give a Stribeck velocity > 0 rad/s for every joint whose peak is not zero")
        # Joints without a hump keep a harmless velocity (a {joint: value} map leaves the others at 0).
        friction["stribeck"] = (peak, np.where(peak > 0, velocity, 1.0))
        record["stribeck"] = {"peak": dict(zip(joints, peak.tolist())),
                              "velocity": dict(zip(joints, velocity.tolist()))}
    if "after_sensor" in coulomb:
        after = _per_joint(coulomb["after_sensor"], joints, f"{where}/after_sensor", path)
        if not np.all((after >= 0) & (after <= 1)):
            raise InputError(path, f"{where}/after_sensor", "a fraction is outside 0..1",
                             "give the share of each joint's friction acting after the sensor, 0 to 1")
        friction["after"] = after
        record["after_sensor"] = dict(zip(joints, after.tolist()))
    return friction


def passive_friction(qd: np.ndarray, friction: Mapping[str, Any]) -> np.ndarray | None:
    """The lab's friction applied as a passive torque (Gaz + Stribeck + the load friction at its present level + the
    hysteretic friction's present state), along qd; None when there is none."""
    out = None
    if friction["gaz"] is not None:
        out = gaz_friction(qd, *friction["gaz"])
    if friction["stribeck"] is not None:
        hump = stribeck_friction(qd, *friction["stribeck"])
        out = hump if out is None else out + hump
    if friction.get("load_level") is not None:
        loaded = friction["load_level"] * np.tanh(qd / LOAD_SMOOTHING_RAD_S)
        out = loaded if out is None else out + loaded
    if friction.get("warm_level") is not None:
        warming = friction["warm_level"] * np.tanh(qd / LOAD_SMOOTHING_RAD_S)
        out = warming if out is None else out + warming
    if friction.get("dahl") is not None:
        level, _ = friction["dahl"]
        memory = level * friction["dahl_state"]
        out = memory if out is None else out + memory
    return out


def dahl_step(state: np.ndarray, displacement: np.ndarray, presliding: np.ndarray) -> np.ndarray:
    """Dahl's friction state after a displacement (z' = (1 - z sign(dq)) dq / presliding, |z| <= 1): the friction
    torque level * z rises along the motion from its value at the last reversal towards the sliding level, over a
    few presliding lengths, and keeps its sign until the motion has reversed far enough (hysteresis)."""
    return np.clip(state + (1.0 - state * np.sign(displacement)) * displacement / presliding, -1.0, 1.0)


def _hysteretic_friction(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                         truth: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """``hysteretic_friction``'s (level N*m, presliding length rad) per joint, or None; recorded in ``truth``."""
    hidden = effects.get("hysteretic_friction")
    if not hidden:
        return None
    where = "hysteretic_friction"
    level = _per_joint(hidden["level"], joints, f"{where}/level", path)
    presliding = _per_joint(hidden["presliding_rad"], joints, f"{where}/presliding_rad", path)
    if np.any(level < 0) or np.any(~(presliding > 0)):
        raise InputError(path, where, "a level is negative or a presliding length is not positive",
                         "give levels >= 0 N*m and presliding lengths > 0 rad")
    truth[where] = {"level": dict(zip(joints, level.tolist())), "presliding_rad": dict(zip(joints, presliding.tolist()))}
    return level, presliding


# The load friction's sign is tanh(qd / this): smooth enough for the explicit passive torque at 1 kHz on a wrist
# (slope level / 0.02 N*m*s/rad at rest).
LOAD_SMOOTHING_RAD_S = 0.02


def _load_friction(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                   truth: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """``load_friction``'s (static N*m, load_coefficient) per joint, or None; recorded in ``truth``. The simulation
    applies it as a passive torque level * tanh(qd / :data:`LOAD_SMOOTHING_RAD_S`), the level
    static + load_coefficient * |transmitted torque| set anew at every control step (:func:`load_friction_level`)."""
    hidden = effects.get("load_friction")
    if not hidden:
        return None
    where = "load_friction"
    static = _per_joint(hidden["static"], joints, f"{where}/static", path)
    coefficient = _per_joint(hidden["load_coefficient"], joints, f"{where}/load_coefficient", path)
    if not np.all(np.isfinite(static) & np.isfinite(coefficient)) or np.any(static < 0) or np.any(coefficient < 0):
        raise InputError(path, where, "a static level or a load coefficient is negative or not finite",
                         "give static levels >= 0 N*m and load coefficients >= 0 (N*m of friction per N*m of load)")
    truth[where] = {"static": dict(zip(joints, static.tolist())),
                    "load_coefficient": dict(zip(joints, coefficient.tolist()))}
    return static, coefficient


def load_friction_level(transmitted: np.ndarray, load: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The dry friction level of each joint under the torque its gear transmits to the link (the rigid-body inverse
    dynamics of the real arm, without the drive's terms): static + load_coefficient * |transmitted|."""
    static, coefficient = load
    return static + coefficient * np.abs(transmitted)


def _cogging(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
             truth: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """``cogging``'s (amplitude N*m, period rad) per joint, or None: a detent torque amplitude*sin(2 pi q / period)
    that the joint's own position decides (a motor's cogging, a harmonic drive's ripple); recorded in ``truth``."""
    hidden = effects.get("cogging")
    if not hidden:
        return None
    amplitude = _per_joint(hidden["amplitude"], joints, "cogging/amplitude", path)
    period = _per_joint(hidden.get("period_rad", 1.0), joints, "cogging/period_rad", path)
    if np.any((amplitude != 0) & ~(period > 0)) or not np.all(np.isfinite(period)):
        raise InputError(path, "cogging/period_rad", "a joint with an amplitude has no positive period",
                         "give a period > 0 rad for every joint whose amplitude is not zero")
    period = np.where(amplitude != 0, period, 1.0)  # joints without a ripple keep a harmless period
    truth["cogging"] = {"amplitude": dict(zip(joints, amplitude.tolist())), "period_rad": dict(zip(joints, period.tolist()))}
    return amplitude, period


def _warming_friction(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                      truth: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, float] | None:
    """``warming_friction``'s (level N*m, ease, time constant s), or None: a dry friction that eases as the joint
    warms, level * (1 + ease * exp(-t / time_constant_s)) from each run's start (the grease thins as it warms), applied
    as level(t) * tanh(qd / :data:`LOAD_SMOOTHING_RAD_S`); recorded in ``truth``."""
    hidden = effects.get("warming_friction")
    if not hidden:
        return None
    where = "warming_friction"
    level = _per_joint(hidden["level"], joints, f"{where}/level", path)
    ease = _per_joint(hidden.get("ease", 0.5), joints, f"{where}/ease", path)
    constant = float(hidden.get("time_constant_s", 10.0))
    if np.any(level < 0) or np.any(ease < 0) or not constant > 0:
        raise InputError(path, where, "a level or an ease is negative, or the time constant is not positive",
                         "give levels >= 0 N*m, eases >= 0 (the cold level's excess over the warm one, as a fraction) "
                         "and a time constant > 0 s")
    truth[where] = {"level": dict(zip(joints, level.tolist())), "ease": dict(zip(joints, ease.tolist())),
                    "time_constant_s": constant}
    return level, ease, constant


def warming_level(elapsed: float, warming: tuple[np.ndarray, np.ndarray, float]) -> np.ndarray:
    """The warming friction's level per joint ``elapsed`` seconds into the run."""
    level, ease, constant = warming
    return level * (1.0 + ease * np.exp(-elapsed / constant))


def cogging_torque(q: np.ndarray, cogging: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    amplitude, period = cogging
    return amplitude * np.sin(2.0 * np.pi * q / period)


def _cable_spring(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                  truth: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``cable_spring``'s (stiffness N*m/rad, rest rad, width rad) per joint, or None: a cable harness pulling each
    joint towards a rest posture (:func:`cable_spring_torque`); recorded in ``truth``."""
    hidden = effects.get("cable_spring")
    if not hidden:
        return None
    stiffness = _per_joint(hidden["stiffness"], joints, "cable_spring/stiffness", path)
    rest = _per_joint(hidden.get("rest_rad", 0.0), joints, "cable_spring/rest_rad", path)
    width = _per_joint(hidden.get("width_rad", 0.3), joints, "cable_spring/width_rad", path)
    if np.any(stiffness < 0) or np.any(~(width > 0)):
        raise InputError(path, "cable_spring", "a stiffness is negative or a width is not positive",
                         "give stiffnesses >= 0 N*m/rad and widths > 0 rad")
    truth["cable_spring"] = {"stiffness": dict(zip(joints, stiffness.tolist())), "rest_rad": dict(zip(joints, rest.tolist())),
                             "width_rad": dict(zip(joints, width.tolist()))}
    return stiffness, rest, width


def cable_spring_torque(q: np.ndarray, spring: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """-stiffness * width * tanh((q - rest) / width): stiff near the rest posture, saturating beyond ``width``."""
    stiffness, rest, width = spring
    return -stiffness * width * np.tanh((q - rest) / width)


def _torque_drift(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None, seed: int,
                  truth: dict[str, Any], time: np.ndarray) -> np.ndarray | None:
    """``torque_drift``: each joint's torque sensor warms up, its offset drifting as level * (1 - exp(-t/tau)),
    the level a different draw in every run (between 0.5 and 1.5 times ``amplitude``, either sign), like a
    sensor whose offset settles anew each time the arm starts. (N, n) or None."""
    hidden = effects.get("torque_drift")
    if not hidden:
        return None
    amplitude = _per_joint(hidden["amplitude"], joints, "torque_drift/amplitude", path)
    tau = float(hidden.get("time_constant_s", 5.0))
    if not tau > 0:
        raise InputError(path, "torque_drift/time_constant_s", "is not positive", "give a warm-up time constant > 0 s")
    draw = np.random.default_rng(seed + 104729)
    level = amplitude * draw.uniform(0.5, 1.5, size=len(joints)) * draw.choice([-1.0, 1.0], size=len(joints))
    truth["torque_drift"] = {"amplitude": dict(zip(joints, amplitude.tolist())), "time_constant_s": tau}
    return level[None, :] * (1.0 - np.exp(-(time - time[0])[:, None] / tau))

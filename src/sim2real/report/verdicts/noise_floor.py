"""The noise floor in words: which floor every "x floor" figure, weight, the ceiling and the stopping rule use
(sim2real.measurements.noise.measured_noise_floor, gap.json's noise_floor.method and noise_floor.evidence), and the
figures that show it where differences could not measure it (:func:`floor_sentences`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

FLOOR_METHOD_TEXT = {
    "differences": "the white part of the raw torque (differences of orders 2 to 5 agree)",
    "rounding": "the RMS of the logger's rounding (quantum/sqrt(12): its differences are mostly zero)",
    "updates": "the white part of the joint's own updates (the samples where its torque changes)",
    "spectrum": "the spectrum of the raw torque above the motion's band, up to the sensor chain's cut-off",
    "stated": "the floor the runs' metadata state",
}


def _joint_list(joints: Sequence[str]) -> str:
    return ", ".join(joints)


def floor_sentences(noise_floor: Mapping[str, Any]) -> list[str]:
    """What gap.md says of the noise floor: which floor it is per joint, and, where differences could not measure it,
    the figures that show it (gap.json's ``noise_floor``: ``method`` per joint, ``evidence`` per run)."""
    methods: Mapping[str, str] = noise_floor.get("method") or {}
    by_method: dict[str, list[str]] = {}
    for joint, method in methods.items():
        by_method.setdefault(method, []).append(joint)
    sentences = [f"The noise floor on {_joint_list(joints)} is {FLOOR_METHOD_TEXT.get(m.split('+')[0], m)}."
                 if len(by_method) > 1 else f"The noise floor is {FLOOR_METHOD_TEXT.get(m.split('+')[0], m)}, on every joint."
                 for m, joints in by_method.items()]
    for run in noise_floor.get("evidence") or []:
        sentences += _floor_evidence(run)
    return sentences


def _floor_evidence(run: Mapping[str, Any]) -> list[str]:
    """The figures of one run whose floor is not the differences' white part on every joint."""
    out = []
    figures = run["joints"]
    held = [j for j, f in figures.items() if f["method"] == "updates" or (f["method"] == "spectrum" and f["held"])]
    falling = [j for j, f in figures.items() if f["method"] == "spectrum" and not f["held"]]
    if held:
        shares = ", ".join(f"{j} {figures[j]['equal_steps']:.0%}" for j in held)
        out.append(f"Run {run['run']}: the floor could not be taken from differences on {_joint_list(held)}: most "
                   f"consecutive torque samples are equal ({shares}), so differences give about zero; the torque is held "
                   f"between updates slower than the log.")
    if falling:
        spans = ", ".join(f"{j} {figures[j]['differences'][0]:.3g} -> {figures[j]['differences'][-1]:.3g} N m against "
                          f"{figures[j]['spectrum']:.3g} N m" for j in falling)
        out.append(f"Run {run['run']}: the floor could not be taken from differences on {_joint_list(falling)}: their "
                   f"estimates keep falling with the order (order 2 -> 5), below what the spectrum holds ({spans}); the "
                   f"torque was smoothed, held or upsampled before it was logged.")
    stated = [j for j, f in figures.items() if f["method"] == "stated"]
    if stated:
        out.append(f"Run {run['run']}: the floor on {_joint_list(stated)} is the one its metadata state: "
                   f"{run['stated_reason']}.")
    return out

"""What the sides can tell apart, in words: what the runs log and so which side judges what (gap.json's ``links``:
:func:`sides_section`), and what the actuator link judges by the sensor's placement (:func:`judged_text`)."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

from sim2real.identification.records import SensorPlacement

MODE_TEXT: dict[str, str] = {
    "separate": "the runs log the measured torque (tau) and the command (tau_cmd): the actuator link is judged "
    "on tau against tau_cmd, the body link on tau against the motion",
    "commands_only": "the runs log only the command (tau_cmd): the actuator and the body are judged together, "
    "on tau_cmd against the motion",
    "sensor_only": "the runs log only the measured torque (tau): the body link is judged on tau against the "
    "motion; the actuator (command -> applied torque) cannot be seen",
}


def _why(why: str, sensor: SensorPlacement) -> str:
    """Why a group of effects can or cannot be told apart (:func:`sim2real.identification.sides.separability`)."""
    link_side, motor_side = sensor == SensorPlacement.LINK_SIDE, sensor == SensorPlacement.MOTOR_SIDE
    return {
        "drive_against_command": "judged on the measured torque against the command: no body effect enters that link"
        + (" (the sensor is link-side: the drive's rotor inertia and friction lie before it)" if link_side else "")
        + "; the sensor's own lag does (its reading lags the command too): the calibrated actuation lag is "
        "what this link finds beyond the body link's (sensor_delay, sensor_lag)",
        "body_against_motion": "judged on the measured torque against the motion: no actuator effect enters that link"
        + (" (the sensor is motor-side: the drive's rotor inertia and friction lie after it)" if motor_side else ""),
        "lag_of_whole_torque": "a lag of the whole torque (a delay, or a filter's), which no body effect makes; the "
        "replay of each rung (replay position RMSE) shows it in the state domain too",
        "constant_torque": "a constant torque per joint; no body effect of the library is constant",
        "common_gain": "a motor gain g common to all joints moves the arm exactly as the body with every torque "
        "scaled by 1/g (masses, inertias, armature and friction together): in the torque domain and in "
        "the replay alike. Only per-joint differences of the gain show. A joint torque sensor (tau) "
        "separates them",
        "no_sensor": "errors of a torque sensor, and these runs have none: not tried",
        "no_command": "the runs log no command (tau_cmd), so the actuator link is not seen: not fitted, not tried"
        + ("; the drive's effects are tried on the body link, where the measured torque shows what acts "
           "after the sensor" if link_side else ""),
        "confounded": "on these runs their fitted models predict the same torque (within a tenth of the noise floor)",
    }[why]


def sides_section(links: Mapping[str, Any]) -> dict[str, Any]:
    """gap.json's ``links``: ladder.json's with its words (one that has them already as it is)."""
    if "text" in links:
        return copy.deepcopy(dict(links))
    sensor = links.get("torque_sensor", SensorPlacement.MOTOR_SIDE)
    out = {key: copy.deepcopy(value) for key, value in links.items() if key != "drive_after_sensor"}
    out["text"] = MODE_TEXT[links["mode"]]
    for group in (*out["can_tell"], *out["cannot_tell"]):
        group["why"] = _why(group["why"], sensor)
    if links.get("drive_after_sensor"):
        out["metadata_note"] = (
            f"The runs say the torque sensor is link-side (torque_sensor: link), so the body link was expected to be "
            f"the rigid body alone; yet the model fits {', '.join(links['drive_after_sensor'])} on it, against the "
            "motion, after the sensor. The data say part of the joint's friction or inertia acts after the sensor "
            "(output bearings, seals) or that the sensor sits before part of the drive; the calibrated model adds it "
            "to the joint's value.")
    return out


def judged_text(sensor: SensorPlacement) -> str:
    """What the actuator link judges, by the sensor's placement."""
    if sensor == SensorPlacement.MOTOR_SIDE:
        return "measured torque (tau) predicted from the commanded torque (tau_cmd); no dynamics"
    return ("link-side measured torque (tau) predicted from the commanded torque (tau_cmd) less the drive's rotor "
            "inertia, damping and friction on the measured motion")

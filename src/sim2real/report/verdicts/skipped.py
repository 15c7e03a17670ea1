"""Why a candidate was not tried (a skipped trial's note), in words: :func:`skip_reason`."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from sim2real.identification.records import Note, NoteKind

SKIP_TEXT: dict[NoteKind, Callable[[Mapping[str, Any]], str]] = {
    NoteKind.PER_RUN: lambda f: (
        "estimated on every run itself, the holdout runs included, so no held-out run can judge it: the model-free "
        "ceiling says when each run's offsets call for it, and the user declares it"),
    NoteKind.NESTED: lambda f: f"{f['holder']} in the model already holds it (a special case of it)",
    NoteKind.DRIVE_BEHIND_SENSOR: lambda f: (
        "an effect of the actuator link (command -> applied torque), and the torque judged here is measured by a "
        "sensor (tau) after it; runs that also log tau_cmd judge it on the actuator link"),
    NoteKind.SENSOR_ON_COMMANDS: lambda f: (
        "an error of the torque sensor, and these runs judge the commanded torque (tau_cmd): on commands the same "
        "column is the actuator's (actuator_gain, command_bias)"),
    NoteKind.LAG_SCREENED: lambda f: (
        f"a {'lead of the judged torque ahead of' if f['lead'] else 'lag of the measured torque behind'} the model "
        f"({f['delay_s'] * 1e3:.2g} ms, linearised about none, every linear coefficient refitted beside it on the "
        f"holdout runs) would remove at most {f['share']:.0%} of what lies above the noise floor, under half of what "
        "names a candidate"),
    NoteKind.OTHER_SHAPE: lambda f: (
        f"its other shape, {f['other']}, tried beside it, removes {f['share']:.0%} of what lies above the noise "
        "floor, under half of what names a candidate"),
    NoteKind.RIPPLE_AT_FLOOR: lambda f: (
        "every joint's residual is within its noise floor times the diagnosis's factor: no joint's ripple to search "
        "for"),
}


def skip_reason(note: Note) -> str:
    """Why a candidate was not tried."""
    if note.kind == NoteKind.RIPPLE_SCREENED:
        f = note.figures
        return ("no joint's residual repeats with its own position: one sinusoid of each joint's position, its period "
                f"and coefficients fitted on the fit runs, would remove at most {f['share']:.0%} of what lies above the "
                f"noise floor of the holdout runs ({f['joint_share']:.0%} on {note.joints[0]}), under half of what "
                "names a candidate")
    return SKIP_TEXT[note.kind](note.figures)

"""How the verdicts name what they share: the sides, the bounds a consistent fit holds a body at, and the runs
that would tell two effects apart."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sim2real.excitation.names import separation_name
from sim2real.identification.records import Side

# How each side is named in verdicts (the documents' words: the body link, the actuator link).
SIDE_TEXT: dict[str, str] = {
    Side.BODY: "the body link (measured torque against the motion)",
    Side.DRIVE: "the actuator link (measured against commanded torque)",
    Side.COMBINED: "the commanded torque against the motion (actuator and body together: no torque sensor)",
}
# A side as a note on the other side names it ("the actuator link").
SIDE_NAME: dict[str, str] = {Side.BODY: "body", Side.DRIVE: "actuator", Side.COMBINED: "combined"}

# A bound of the consistent fit that binds (sim2real.identification.inertial.bands.binding), as gap.md says it.
BOUND_TEXT = {"mass_lower": "mass at its band's lower edge", "mass_upper": "mass at its band's upper edge",
              "hull": "centre of mass on its hull", "divergence": "divergence from CAD at its bound"}

def bounds_text(bodies: Mapping[str, Sequence[str]] | Sequence[Sequence[Any]]) -> str:
    """Bodies held at their bounds, with which: a mapping, or (body, bounds) pairs in the bodies' order."""
    pairs = bodies.items() if isinstance(bodies, Mapping) else bodies
    return "; ".join(f"{name} ({', '.join(BOUND_TEXT[b] for b in bounds)})" for name, bounds in pairs)


def separating_runs(first: str, others: Sequence[str], robot: str) -> str:
    return "; ".join(f"`snakemake results/{robot}/excitation/{separation_name(first, other)}.csv`" for other in others)

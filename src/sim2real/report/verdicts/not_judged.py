"""The joints the fit runs barely move, in words (gap.json's ``not_judged``): :func:`not_judged_text`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

def not_judged_text(not_judged: Mapping[str, Any]) -> str:
    """The joints the fit runs barely move (gap.json's ``not_judged``: sim2real.measurements.motion), in one sentence:
    not judged, what the fit holds of them, and the motion they would need."""
    joints = list(not_judged["joints"])
    one = len(joints) == 1
    ranges = " and ".join(f"{not_judged['joints'][j]['range_rad']:.2g}" for j in joints)
    return (f"Not judged: {', '.join(joints)} barely {'moves' if one else 'move'} in the fit runs ({ranges} rad at most "
            f"within one run): {'its' if one else 'their'} {' and '.join(not_judged['held_at_nominal'])} are held at "
            f"the URDF's rather than fitted on noise, and the figures below judge nothing of "
            f"{'its drive' if one else 'their drives'}; record a fit run that sweeps {'it' if one else 'each'} over "
            f"at least {not_judged['needs_rad']:g} rad.")

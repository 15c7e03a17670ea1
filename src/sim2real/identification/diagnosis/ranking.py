"""The order of a diagnosis's candidates (:func:`_rank`: decisive first, then by what each removes, the simplest of
those that do as well first) and the pairs these runs cannot tell apart (:func:`_confounded`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.diagnosis.lags import same_lag
from sim2real.identification.effects import EFFECTS


def _rank(candidates: list[dict[str, Any]], tolerance: float) -> list[dict[str, Any]]:
    """Decisive candidates first, each group by explained share; then the simplest candidate that does as
    well as the best goes first.

    Effects nest (a payload is a change of the last link's inertia; link_inertia holds it): the
    bigger one always explains a little more, the smaller one is the better name for what is missing.
    "As well" is judged in units of the noise floor: within ``tolerance`` of the best holdout residual
    (each joint in units of its own floor), a difference no excitation of this length can tell from noise.
    """
    ranked = sorted(candidates, key=lambda c: (not c["decisive"], -c["explained"], c["effect"]))
    if not ranked:
        return ranked
    best = ranked[0]
    if not best["decisive"]:
        return ranked  # nothing is named: the order is only what comes closest
    limit = best["evidence"].x_floor_after + tolerance
    close = [c for c in ranked if c["decisive"] == best["decisive"] and c["evidence"].x_floor_after <= limit]
    # Among those that do as well, one that keeps every inertia plausible first, then one that pushes fewer bounds
    # (the one that leaves the links freer names what acted like mass), then the simplest: of two shapes of one lag,
    # the delay (a filter gives the simulation a state of its own).
    simplest = min(close, key=lambda c: (bool(c["evidence"].implausible_bodies), c["evidence"].bounds_pushed_net,
                                         c["evidence"].parameters,
                                         EFFECTS[c["effect"]].lowpass, -c["explained"], c["effect"]))
    return [simplest] + [c for c in ranked if c is not simplest]


def _confounded(candidates: Sequence[Mapping[str, Any]], residuals: Mapping[str, np.ndarray], tolerance: float,
                min_gain: float) -> list[tuple[str, str]]:
    """Pairs of candidates that each remove at least ``min_gain`` of the residual and predict the same
    holdout torque to within ``tolerance`` (RMS in floor units): on these data one is the other (ranked order).
    ``residuals`` are already in floor units."""
    useful = [c["effect"] for c in candidates if c["explained"] >= min_gain]
    pairs = []
    for i, a in enumerate(useful):
        for b in useful[i + 1 :]:
            if same_lag(a, b):
                continue  # two shapes of one lag: no run separates them (the verdict's shape sentence says so)
            if float(np.sqrt(np.mean((residuals[a] - residuals[b]) ** 2))) <= tolerance:
                pairs.append((a, b))
    return pairs

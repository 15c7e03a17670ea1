"""Where a link's identified inertia may lie (:class:`InertiaBands`), as constraints of the consistent fit.

A real arm's CAD inertias are off by tens of percent, not by half a link; a centre of mass lies inside the link's
collision hull; a link the data bend far from its CAD mass distribution soaks up an effect the model lacks. These were
a flag written after the fit; they are now constraints of the fit itself (FloBaRoID's ``limitMassToApriori`` and
``restrictCOMtoHull``, Wensing et al. 2017's bounding ellipsoid, a bounded entropic divergence), each convex:

* the mass band ``(1 - f) m0 <= m <= (1 + f) m0`` is linear in ``m``;
* the centre of mass inside the hull, ``n . c + d <= tol`` for every facet, is ``n . h + (d - tol) m <= 0`` with
  ``h = m c``: linear in ``(m, h)`` (``m > 0`` holds by consistency);
* the divergence ``tr(J~) - log det J~ - 4 <= D`` is a log-det cone, already in the program for the prior.

The body that carries tools (the last) keeps its freedom to gain any mass, as a tool or payload does: it has no upper
mass bound, no hull and no divergence bound (only its ellipsoid, and the lower mass bound). The hull binds a body only
where its CAD centre of mass lies inside it (else the meshes do not say where that link's mass is).

:func:`body_bounds` lays out each body's bounds once; :func:`binding` says which bind at a solution. The plausibility
of :mod:`sim2real.identification.effects.link_inertia` judges with the same bounds, so a consistent fit cannot be
called implausible: the flag and the constraints are one rule.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

# The bounds the program holds sit this far inside the bands the flag judges by: the solver's tolerance (1e-11) and
# the document's rounding (masses to 6 decimals) then never put a solution beyond a band.
MASS_MARGIN = 1e-5  # of the CAD mass
HULL_MARGIN_M = 1e-5
DIVERGENCE_MARGIN = 1e-4
# A bound binds when the solution lies within this fraction of the band's width of it (the prior's pull to CAD makes
# an interior solution sit well inside).
BINDING_FRACTION = 0.01


@dataclass(frozen=True)
class InertiaBands:
    """How far an identified link may lie from its CAD values (``robot.yaml`` ``inertia_bands``)."""

    mass_fraction: float = 0.5  # CAD masses of a built arm are off by tens of percent, not half the link
    hull_tolerance_m: float = 0.005  # collision meshes are simplified and cables ride outside them
    # Entropic divergence from CAD (dimensionless). Measured on the Panda lab demo (real_arm_like, 20 s runs): the
    # complete rung ends at <= 2.0 on inner links; the lab's hidden CAD errors themselves (mass +-25 %, COM 25 mm) are
    # 0.1-2.5 on all links but the thin link 2; rungs still missing friction or the sensor bias reached 6-55 on some
    # link without the bound, and a real Panda's logs 11-36.
    divergence: float = 5.0

    @classmethod
    def of_robot(cls, robot_config: Mapping[str, Any] | None) -> InertiaBands:
        """The bands of a robot.yaml's content (``inertia_bands``: ``mass_fraction``, ``hull_tolerance_mm``,
        ``divergence``; schemas/robot.schema.yaml), the defaults where it names none."""
        given = dict((robot_config or {}).get("inertia_bands") or {})
        default = cls()
        return cls(mass_fraction=float(given.get("mass_fraction", default.mass_fraction)),
                   hull_tolerance_m=float(given.get("hull_tolerance_mm", 1000.0 * default.hull_tolerance_m)) / 1000.0,
                   divergence=float(given.get("divergence", default.divergence)))


@dataclass(frozen=True)
class BodyBounds:
    """One body's bounds in the program's terms, around its anchor (the parameters its correction is added to).

    ``mass``: (lower, upper) of the corrected mass (upper inf for the tool body); ``hull``: facets ``(k, 4)`` as
    ``n . c + d <= 0`` with the tolerance and margin folded into ``d``, or None; ``divergence``: the bound of its
    entropic divergence from its anchor (inf for the tool body)."""

    mass: tuple[float, float]
    hull: np.ndarray | None
    divergence: float


def _cad_inside(anchor: np.ndarray, hull: np.ndarray, tolerance: float) -> bool:
    com = anchor[1:4] / anchor[0]
    return bool(np.max(hull[:, :3] @ com + hull[:, 3]) <= tolerance)


def body_bounds(anchors: np.ndarray, hulls: Sequence[np.ndarray | None] | None, bands: InertiaBands,
                margins: bool = True) -> list[BodyBounds]:
    """Every body's :class:`BodyBounds` (the last carries tools); ``margins``: the program's (inside the bands by
    the margins above) or the bands themselves (what the flag judges by)."""
    anchors = np.asarray(anchors, dtype=float).reshape(-1, 10)
    hulls = list(hulls) if hulls else [None] * len(anchors)
    mass_margin = MASS_MARGIN if margins else 0.0
    hull_margin = HULL_MARGIN_M if margins else 0.0
    out = []
    for b, anchor in enumerate(anchors):
        tool = b == len(anchors) - 1
        m0 = float(anchor[0])
        lower = m0 * (1.0 - bands.mass_fraction + mass_margin)
        upper = np.inf if tool else m0 * (1.0 + bands.mass_fraction - mass_margin)
        hull = hulls[b] if b < len(hulls) else None
        if tool or hull is None or m0 <= 0 or not _cad_inside(anchor, hull, bands.hull_tolerance_m):
            folded = None
        else:
            folded = np.asarray(hull, dtype=float).copy()
            folded[:, 3] -= bands.hull_tolerance_m - hull_margin
        divergence = np.inf if tool else bands.divergence - (DIVERGENCE_MARGIN if margins else 0.0)
        out.append(BodyBounds((lower, upper), folded, divergence))
    return out


def binding(bounds: BodyBounds, anchor: np.ndarray, corrected: np.ndarray, divergence: float,
            band_mass_fraction: float) -> list[str]:
    """Which of a body's bounds bind at ``corrected`` (its 10 parameters; ``divergence`` from its anchor): each as
    ``mass_lower``, ``mass_upper``, ``hull`` or ``divergence``. A bound that binds is evidence: the data push the link
    as far as physics lets them, where something the model lacks acts like mass (or a shifted centre of mass)."""
    out = []
    m0, m = float(anchor[0]), float(corrected[0])
    width = max(band_mass_fraction * m0, 1e-9)
    lower, upper = bounds.mass
    if m - lower <= BINDING_FRACTION * width:
        out.append("mass_lower")
    if np.isfinite(upper) and upper - m <= BINDING_FRACTION * width:
        out.append("mass_upper")
    if bounds.hull is not None and m > 0:
        # The hull's facets at the centre of mass, in metres: binding within a fraction of a millimetre.
        if float(np.max(bounds.hull[:, :3] @ (corrected[1:4] / m) + bounds.hull[:, 3])) >= -1e-4:
            out.append("hull")
    if np.isfinite(bounds.divergence) and np.isfinite(divergence) and (
            bounds.divergence - divergence <= BINDING_FRACTION * bounds.divergence):
        out.append("divergence")
    return out

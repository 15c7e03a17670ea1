"""One body's inertial parameters as geometry: the pseudo-inertia (positive definite iff physically consistent),
the entropic divergence from CAD (Lee and Park 2018), bounding ellipsoids of the link's mass, and the block of a
design that holds the link inertias (:class:`InertialBlock`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from sim2real.identification.inertial.bands import BodyBounds

PARAMS_PER_BODY = 10  # Pinocchio order: m, m*c (3), I about the body frame (xx, xy, yy, xz, yz, zz)


PD_MARGIN = 1e-4  # smallest eigenvalue kept, relative to the CAD body's pseudo-inertia (J >= 1e-4 J0)


def pseudo_inertia(params: np.ndarray) -> np.ndarray:
    """4x4 pseudo-inertia matrix of one body's 10 dynamic parameters (PD iff physically consistent)."""
    return pseudo_inertias(np.asarray(params, dtype=float).reshape(1, PARAMS_PER_BODY))[0]


def pseudo_inertias(bodies: np.ndarray) -> np.ndarray:
    """(B, 4, 4) pseudo-inertias of (B, 10) bodies' parameters, in one pass over the stack."""
    bodies = np.asarray(bodies, dtype=float)
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = bodies.T
    half_trace = 0.5 * (ixx + iyy + izz)
    out = np.zeros((len(bodies), 4, 4))
    out[:, 0, 0], out[:, 1, 1], out[:, 2, 2] = half_trace - ixx, half_trace - iyy, half_trace - izz
    out[:, 0, 1] = out[:, 1, 0] = -ixy
    out[:, 0, 2] = out[:, 2, 0] = -ixz
    out[:, 1, 2] = out[:, 2, 1] = -iyz
    out[:, :3, 3] = out[:, 3, :3] = np.stack([hx, hy, hz], axis=1)
    out[:, 3, 3] = m
    return out


# d(pseudo-inertia)/d(parameter k): the pseudo-inertia is linear in the parameters.
PSEUDO_BASIS = np.array([pseudo_inertia(np.eye(PARAMS_PER_BODY)[k]) for k in range(PARAMS_PER_BODY)])


def min_eigenvalues(params: np.ndarray) -> np.ndarray:
    """Smallest pseudo-inertia eigenvalue of every body of a stacked parameter vector."""
    return np.linalg.eigvalsh(pseudo_inertias(np.asarray(params, dtype=float).reshape(-1, PARAMS_PER_BODY))).min(axis=1)


def physically_consistent(params: np.ndarray) -> bool:
    return bool(np.all(min_eigenvalues(params) > 0))


def entropic_divergence(params: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Lee-Park divergence of every body from its reference (inf where a body is not consistent)."""
    relative = np.linalg.solve(pseudo_inertias(np.reshape(reference, (-1, 10))), pseudo_inertias(np.reshape(params, (-1, 10))))
    sign, logdet = np.linalg.slogdet(relative)
    return np.where(sign > 0, np.trace(relative, axis1=1, axis2=2) - logdet - 4.0, np.inf)


def ellipsoid_matrix(center: np.ndarray, axes: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Q of the ellipsoid {x : [x; 1]^T Q [x; 1] >= 0} with semi-axes ``axes`` along ``rotation``'s columns."""
    shape = rotation @ np.diag(1.0 / np.asarray(axes, dtype=float) ** 2) @ rotation.T
    center = np.asarray(center, dtype=float)
    q = np.zeros((4, 4))
    q[:3, :3] = -shape
    q[:3, 3] = shape @ center
    q[3, :3] = shape @ center
    q[3, 3] = 1.0 - center @ shape @ center
    return q


def bounding_ellipsoid(points: np.ndarray) -> np.ndarray:
    """Q of an ellipsoid holding every point: the one through the corners of their oriented bounding box."""
    import trimesh

    to_box, extents = trimesh.bounds.oriented_bounds(np.asarray(points, dtype=float))
    frame = np.linalg.inv(to_box)
    axes = np.sqrt(3.0) / 2.0 * np.maximum(np.asarray(extents, dtype=float), 1e-3)
    return ellipsoid_matrix(frame[:3, 3], axes, frame[:3, :3])


def inside_ellipsoids(params: np.ndarray, ellipsoids: Sequence[np.ndarray | None]) -> list[bool]:
    """tr(J Q) >= 0 per body (True where no ellipsoid is known)."""
    bodies = np.asarray(params, dtype=float).reshape(-1, PARAMS_PER_BODY)
    return [q is None or float(np.trace(pseudo_inertia(b) @ q)) >= -1e-12 for b, q in zip(bodies, ellipsoids)]


@dataclass
class InertialBlock:
    """Where the link corrections sit among the coefficients, and what they correct.

    ``columns``: slice of the design's coefficients that are per-body corrections (10 per body,
    parameter units); ``anchors``: the parameters the corrections are added to, body by body (the
    URDF link that receives them: consistency of it implies consistency of the whole body, which
    also holds the fixed links merged into it); ``ellipsoids``: bounding ellipsoid Q per body or None; ``bounds``:
    each body's mass band, hull and divergence bound (:mod:`sim2real.identification.inertial.bands`; none when
    empty).
    """

    columns: slice
    anchors: np.ndarray  # (n_bodies, 10)
    ellipsoids: list[np.ndarray | None] = field(default_factory=list)
    bounds: list[BodyBounds] = field(default_factory=list)

    @property
    def n_bodies(self) -> int:
        return len(self.anchors)

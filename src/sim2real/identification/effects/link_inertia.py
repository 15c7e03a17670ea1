"""Link inertial parameters: corrections to mass, first moment and inertia of every moving body.

The unconstrained fit works on the identifiable combinations (base parameters): the stacked
regressor of the fit data is reduced by SVD to the directions it excites, and the correction is the
minimum-norm one in those directions, so unexcited directions keep their nominal (URDF) values.
The physically consistent fit (:mod:`sim2real.identification.inertial`, the default) solves for every body's full
10-parameter correction under the pseudo-inertia LMIs with an entropic pull to the CAD link; its
result is stored here as base-parameter coefficients plus the remainder (``null_offset``), so both
fits predict through the same columns.
Pinocchio's dynamic parameter order per body: m, m*c (3), I about the joint frame
(xx, xy, yy, xz, yz, zz).
"""

from __future__ import annotations

import functools

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, Signature, explained_per_joint, per_joint_dict,
)
from sim2real import blas
from sim2real.identification.inertial import entropic_divergence, physically_consistent
from sim2real.identification.inertial.bands import BodyBounds, InertiaBands, binding, body_bounds

RELATIVE_SINGULAR_TOL = 1e-3  # directions excited 1000x less than the best are left at nominal
STRUCTURAL_ZERO = 1e-9  # relative column norm below which a parameter does not act at all
KEPT_COLUMNS_BYTES = 32 * 2**20  # the columns kept with their signals up to this size (a 20 s log: 8 MB)
# A body "moved" when the fit changed it beyond these (else it stayed at its URDF values).
MOVED_MASS_FRACTION = 0.02
MOVED_COM_M = 0.003
MOVED_DIVERGENCE = 1e-3
# A body is *implausible* beyond the bands of :class:`sim2real.identification.inertial.bands.InertiaBands` (robot.yaml
# ``inertia_bands``), which the consistent fit holds as constraints: only an unconstrained fit can leave them.


def parameter_scales(inertial: np.ndarray) -> np.ndarray:
    """Typical size of each dynamic parameter of each body: m, m*0.1 m, m*(0.1 m)^2."""
    scales = []
    for b in range(len(inertial) // 10):
        mass = max(abs(float(inertial[10 * b])), 0.1)
        scales.append([mass] + [0.1 * mass] * 3 + [0.01 * mass] * 6)
    return np.asarray(scales, dtype=float).reshape(-1)


def to_mass_com_inertia(params: np.ndarray) -> dict[str, Any]:
    """One body's dynamic parameters -> mass, center of mass, inertia about the COM (xx, xy, xz, yy, yz, zz)."""
    return bodies_mass_com_inertia(np.asarray(params, dtype=float).reshape(1, 10))[0]


def bodies_mass_com_inertia(bodies: np.ndarray) -> list[dict[str, Any]]:
    """:func:`to_mass_com_inertia` of each of (B, 10) bodies, computed for the stack at once (the bootstrap asks
    for every body of every replicate)."""
    bodies = np.asarray(bodies, dtype=float)
    m = bodies[:, 0]
    heavy = np.abs(m) > 1e-12
    c = np.where(heavy[:, None], bodies[:, 1:4] / np.where(heavy, m, 1.0)[:, None], 0.0)
    ixx, ixy, iyy, ixz, iyz, izz = bodies[:, 4:10].T
    squared = np.sum(c * c, axis=1)
    # I_com = I_origin - m (|c|^2 1 - c c'), entry by entry in the order xx, xy, xz, yy, yz, zz
    inertia = np.stack([ixx - m * (squared - c[:, 0] * c[:, 0]), ixy + m * c[:, 0] * c[:, 1], ixz + m * c[:, 0] * c[:, 2],
                        iyy - m * (squared - c[:, 1] * c[:, 1]), iyz + m * c[:, 1] * c[:, 2],
                        izz - m * (squared - c[:, 2] * c[:, 2])], axis=1)
    return [{"mass": round(float(mb), 6), "com": [round(v, 6) for v in cb], "inertia": [round(v, 8) for v in ib]}
            for mb, cb, ib in zip(m.tolist(), c.tolist(), inertia.tolist(), strict=True)]


def correction_anchors(nominal: dict[str, Any]) -> np.ndarray:
    """Per body, the parameters its correction is added to: the URDF link that receives it.

    The calibrated URDF writes a body's correction into its joint's child link; keeping that link
    consistent keeps the whole body consistent (the fixed links merged into it are consistent on
    their own). A massless child link falls back to the whole body.
    """
    total = np.asarray(nominal["inertial"], dtype=float).reshape(-1, 10)
    own = nominal.get("link_own_inertial", {})
    links = tuple(nominal["body_links"])
    # A pure function of these numbers, asked for by every bootstrap replicate's values: kept by their bytes.
    return _anchors(total.tobytes(), links, tuple(
        np.asarray(own[link], dtype=float).tobytes() if link in own else b"" for link in links)).copy()


@functools.lru_cache(maxsize=16)
def _anchors(total: bytes, links: tuple[str, ...], own: tuple[bytes, ...]) -> np.ndarray:
    bodies = np.frombuffer(total, dtype=float).reshape(-1, 10)
    anchors = []
    for b, link_own in enumerate(own[: len(links)]):
        candidate = np.frombuffer(link_own, dtype=float) if link_own else bodies[b]
        anchors.append(candidate if physically_consistent(candidate) else bodies[b])
    return np.asarray(anchors)


def hull_distance(point: np.ndarray, equations: np.ndarray) -> float:
    """Signed distance [m] of a point beyond a convex hull's farthest facet plane (``n . x + d``, unit ``n``).

    Negative inside (minus the depth), positive outside: exact where the nearest hull point lies on a
    facet, a lower bound near edges and corners (so a point is never called farther out than it is).
    """
    return float(np.max(equations[:, :3] @ np.asarray(point, dtype=float) + equations[:, 3]))


def plausibility(before: dict[str, Any], after: dict[str, Any], divergence: float, hull: np.ndarray | None,
                 bounds: BodyBounds) -> dict[str, Any]:
    """Whether one identified body lies within its bands (``bounds``: :func:`sim2real.identification.inertial.bands.body_bounds`
    without margins, the same bounds the consistent fit holds): its mass in its band around CAD, its centre of mass
    inside its collision meshes' convex hull ``hull`` (within the tolerance folded into ``bounds.hull``), its divergence
    from CAD bounded; the reasons if not.

    ``com_inside_hull`` is null where the hull does not bind (none, the last body carries tools, or the CAD COM itself
    lies outside it: then the meshes do not say where this link's mass is). The tool body may gain any mass."""
    reasons = []
    m0, m1 = before["mass"], after["mass"]
    lower, upper = bounds.mass
    if m0 > 0 and not lower <= m1 <= upper:
        reasons.append(f"mass changed by {100 * (m1 - m0) / m0:+.0f}% ({m0:.3g} -> {m1:.3g} kg)")
    inside, outside_mm = None, None
    if bounds.hull is not None and hull is not None:
        inside = bool(hull_distance(after["com"], bounds.hull) <= 0.0)
        outside_mm = round(1000.0 * max(hull_distance(after["com"], hull), 0.0), 1)
        if not inside:
            reasons.append(f"centre of mass {outside_mm:.0f} mm outside the link's convex hull")
    if not np.isfinite(divergence):
        reasons.append("not physically consistent (no divergence from CAD)")
    elif divergence > bounds.divergence:
        reasons.append(f"divergence from CAD {divergence:.3g} (above {bounds.divergence:g})")
    return {"com_inside_hull": inside, "com_outside_hull_mm": outside_mm, "implausible": reasons}


def point_mass(mass: float, position: np.ndarray) -> np.ndarray:
    """The 10 dynamic parameters (Pinocchio's order, inertia about the body frame's origin) of a point mass."""
    x, y, z = np.asarray(position, dtype=float)
    return mass * np.array([1.0, x, y, z, y * y + z * z, -x * y, x * x + z * z, -x * z, -y * z, x * x + y * y])


def with_tool(anchors: np.ndarray, corrected: np.ndarray) -> np.ndarray:
    """``anchors`` (B, 10) with the mass the last body gained in ``corrected`` held as a tool: a point mass where the
    fitted first moment puts it. The last body carries tools (:func:`plausibility`): its divergence then measures what
    the fit bent beyond a tool of that mass, not the tool itself (a 0.5 kg tool on a UR5's 0.19 kg wrist is a
    divergence of 12 from the CAD wrist alone)."""
    gained = float(corrected[-1, 0] - anchors[-1, 0])
    if gained <= 0:
        return anchors
    out = anchors.copy()
    out[-1] += point_mass(gained, (corrected[-1, 1:4] - anchors[-1, 1:4]) / gained)
    return out


def body_changes(delta: np.ndarray, nominal: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Which bodies the fit moved, and by how much (mass, centre of mass, divergence from CAD, the last body's from
    CAD plus the tool it gained: :func:`with_tool`); whether each is still plausible (:func:`plausibility`:
    ``com_inside_hull``, ``com_outside_hull_mm``, ``implausible``) and which of the bounds the consistent fit holds
    bind (``binding``: :func:`sim2real.identification.inertial.bands.binding`)."""
    anchors = correction_anchors(nominal)
    corrected = anchors + np.reshape(delta, anchors.shape)
    divergence = entropic_divergence(corrected, with_tool(anchors, corrected))
    mesh = nominal.get("mesh_bounds")
    hulls = (mesh.hulls if mesh else None) or [None] * len(anchors)
    bands = nominal.get("inertia_bands") or InertiaBands()
    judged, held = body_bounds(anchors, hulls, bands, margins=False), body_bounds(anchors, hulls, bands)
    out = {}
    befores, afters = bodies_mass_com_inertia(anchors), bodies_mass_com_inertia(corrected)
    for b, link in enumerate(nominal["body_links"]):
        before, after = befores[b], afters[b]
        dm = after["mass"] - before["mass"]
        dc = float(np.linalg.norm(np.subtract(after["com"], before["com"])))
        moved = bool(abs(dm) > MOVED_MASS_FRACTION * max(before["mass"], 1e-9) or dc > MOVED_COM_M
                     or divergence[b] > MOVED_DIVERGENCE)
        out[link] = {
            "moved": moved, "mass_change_kg": round(dm, 4), "com_shift_mm": round(1000.0 * dc, 2),
            "divergence": round(float(divergence[b]), 6) if np.isfinite(divergence[b]) else None,
            **plausibility(before, after, float(divergence[b]), hulls[b], judged[b]),
            "binding": binding(held[b], anchors[b], corrected[b], float(divergence[b]), bands.mass_fraction),
        }
    return out


class LinkInertia(Effect):
    in_urdf = True
    name = "link_inertia"
    summary = "wrong link masses, centers of mass or inertias in the robot description"
    signature = "residual explained by the rigid-body regressor (gravity- and acceleration-shaped)"
    parameters = (
        ParameterSpec("mass", "kg", 0.0, 100.0, True, "mass of the body moved by each joint (total)"),
        ParameterSpec("com", "m", -2.0, 2.0, True, "center of mass in the joint frame"),
        ParameterSpec("inertia", "kg*m^2", -10.0, 10.0, True, "inertia about the COM (xx, xy, xz, yy, yz, zz)"),
    )
    joint_local = False

    def prepare(self, signals: Signals) -> dict[str, Any]:
        # The same signals give the same basis: the rungs and candidates of a round compute it once (on a long log
        # this reads the whole regressor). Each fit gets its own dict: set_correction writes into it.
        kept = signals._memo.get("link_inertia.prepare")
        if kept is None:
            kept = signals._memo["link_inertia.prepare"] = self._prepare(signals)
        return {key: value.copy() if isinstance(value, np.ndarray) else value for key, value in kept.items()}

    def _prepare(self, signals: Signals) -> dict[str, Any]:
        y = signals.regressor.reshape(-1, signals.regressor.shape[2])
        n_params = y.shape[1]
        # Work in relative units (parameter / its typical size on that body): the minimum-norm
        # correction and the consistency move are then the smallest *relative* changes to the URDF.
        scale = parameter_scales(np.asarray(signals.nominal["inertial"]))
        # Parameters that (numerically) never act on the measured joints are not identifiable at all. Their norms
        # are summed a chunk of rows at a time (they only meet a threshold: no copy of the regressor for them).
        squares = np.zeros(n_params)
        for start in range(0, y.shape[0], blas.CHUNK_ROWS):
            squares += np.sum((y[start : start + blas.CHUNK_ROWS] * scale) ** 2, axis=0)
        norms = np.sqrt(squares)
        active = np.flatnonzero(norms > STRUCTURAL_ZERO * norms.max())
        ya = y[:, active] * scale[active]  # the scaled active columns, as (y * scale)[:, active] to the bit
        # Eigen-decomposition of the Gram matrix = SVD of the stacked regressor, much cheaper.
        eigval, eigvec = np.linalg.eigh(ya.T @ ya)
        del ya
        order = np.argsort(eigval)[::-1]
        singular = np.sqrt(np.clip(eigval[order], 0.0, None))
        rank = int(np.sum(singular > RELATIVE_SINGULAR_TOL * singular[0]))
        # Basis in parameter units: delta = basis @ beta. The rest of the space barely changes the
        # torque on these data: the fit moves along it only to stay physically consistent.
        condition = float(singular[0] / singular[rank - 1]) if rank else float("inf")
        basis = np.zeros((n_params, rank))
        basis[active] = eigvec[:, order[:rank]] * scale[active, None]
        weak = np.zeros((n_params, len(active) - rank))
        weak[active] = eigvec[:, order[rank:]] * scale[active, None]
        inactive = np.setdiff1d(np.arange(n_params), active)
        structural = np.zeros((n_params, len(inactive)))
        structural[inactive, np.arange(len(inactive))] = scale[inactive]
        null = np.hstack([weak, structural])
        return {"basis": basis, "null": null, "rank": rank, "condition_number": condition,
                "null_offset": np.zeros(n_params)}

    def set_correction(self, state: dict[str, Any], delta: np.ndarray) -> np.ndarray:
        """Store a full correction (parameter units) as base coefficients + remainder; returns the coefficients."""
        basis = state["basis"]
        theta = np.linalg.lstsq(basis, delta, rcond=None)[0] if basis.shape[1] else np.zeros(0)
        state["null_offset"] = delta - basis @ theta
        return theta

    def offset(self, signals, state, theta):
        if not np.any(state["null_offset"]):
            return None
        return signals.regressor @ state["null_offset"]

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        basis = state["basis"]
        labels = [ColumnLabel(f"base_{i}") for i in range(basis.shape[1])]
        # Every rung, way and candidate of a round asks for these columns on the same signals and basis: kept with the
        # signals while they are small (the same product, the same bits), read-only so that no fit can change them.
        kept = signals._memo.get("link_inertia.columns")
        if kept is not None and np.array_equal(kept[0], basis):
            return kept[1], labels
        columns = signals.regressor @ basis
        if columns.nbytes <= KEPT_COLUMNS_BYTES:
            columns.setflags(write=False)
            signals._memo["link_inertia.columns"] = (basis.copy(), columns)
        return columns, labels

    def values(self, theta, nonlinear, signals, state):
        delta = state["basis"] @ theta + state["null_offset"]
        # The reasons as tuples: the bootstrap's intervals (fitting.bootstrap._intervals) walk lists item by item, and
        # replicates flag different numbers of reasons and bodies. JSON and YAML write them as lists.
        bodies_changed = {link: {**body, "implausible": tuple(body["implausible"]), "binding": tuple(body["binding"])}
                          for link, body in body_changes(delta, signals.nominal).items()}
        nominal = np.asarray(signals.nominal["inertial"])
        total = nominal + delta
        bodies = signals.nominal["body_links"]
        # The URDF link alone (without the fixed links Pinocchio merged into its body) plus the
        # correction: what the calibrated URDF's <inertial> must say.
        own = signals.nominal.get("link_own_inertial", {})
        with_own = [(b, link) for b, link in enumerate(bodies) if link in own]
        urdf_links = dict(zip([link for _, link in with_own], bodies_mass_com_inertia(np.array(
            [np.asarray(own[link]) + delta[10 * b : 10 * b + 10] for b, link in with_own]).reshape(-1, 10)), strict=True))
        return {
            "links": dict(zip(bodies, bodies_mass_com_inertia(np.reshape(total, (-1, 10))), strict=True)),
            "urdf_links": urdf_links,
            "base_parameters": int(state["rank"]),
            "condition_number": float(state["condition_number"]),
            "physically_consistent": bool(physically_consistent(correction_anchors(signals.nominal).reshape(-1) + delta)),
            "bodies": bodies_changed,
            "implausible_bodies": tuple(link for link, body in bodies_changed.items() if body["implausible"]),
            "binding_bodies": tuple(link for link, body in bodies_changed.items() if body["binding"]),
        }

    def evidence(self, residual, signals):
        return Signature(
            description=self.signature,
            statistic="per-joint R^2 of residual on the rigid-body regressor",
            per_joint=per_joint_dict(signals.joint_names, explained_per_joint(residual, signals.regressor), 3),
        )

    def apply_to_spec(self, spec, values, context):
        # Used when calibrating an MJCF directly (the ladder's replay); the calibrated MJCF is built from the
        # calibrated URDF, which carries the same values. MJCF bodies are URDF links (same frames).
        import mujoco

        for link, inertial in values.get("urdf_links", {}).items():
            body = spec.body(link)
            if body is None:
                continue
            xx, xy, xz, yy, yz, zz = inertial["inertia"]
            body.mass = float(inertial["mass"])
            body.ipos = [float(c) for c in inertial["com"]]
            # A diagonal inertia + orientation, as MuJoCo stores it (it refuses both forms on one body).
            principal, axes = np.linalg.eigh(np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]))
            if np.linalg.det(axes) < 0:
                axes[:, 0] = -axes[:, 0]
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, axes.reshape(-1))
            body.inertia = principal
            body.iquat = quat
            body.fullinertia = [np.nan] * 6
            body.explicitinertial = True

    def calibration(self, values, calibration):
        for link, inertial in values.get("urdf_links", {}).items():
            xx, xy, xz, yy, yz, zz = inertial["inertia"]
            calibration.setdefault("links", {})[link] = {
                "mass": inertial["mass"],
                "com": list(inertial["com"]),
                "inertia": {"ixx": xx, "ixy": xy, "ixz": xz, "iyy": yy, "iyz": yz, "izz": zz},
            }

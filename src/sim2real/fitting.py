"""The fitting core: torque data, the nominal model, one rung's fit, its prediction and holdout metrics.

The fit works in the torque domain. The judged torque (measured ``tau``, else the command
``tau_cmd``) is predicted as

    tau_judged(t) = [tau_nominal + sum_e A_e(nl_e) theta_e + offsets](t + delay)

where ``tau_nominal`` is Pinocchio's inverse dynamics of the URDF (with the MJCF armature),
``A_e`` are the regressor columns of each effect (:mod:`sim2real.effects`), linear in its
parameters ``theta_e``, ``nl_e`` its few nonlinear parameters (a friction smoothing velocity) and
``delay`` the actuation delay when the model has one. Steps of :func:`fit`:

1. nonlinear refinement of the nonlinear parameters by bounded least squares with the linear
   parameters projected out (variable projection), started from a coarse grid for the delay;
   parameters of effects already in the model can be held (a ladder rung refines only its own);
2. the linear parameters: unconstrained least squares (columns scaled, minimum-norm, link
   inertias as base parameters) and the physically consistent fit (:mod:`sim2real.inertial`: one
   convex program with the pseudo-inertia LMIs and sign bounds), which the rung reports;
3. uncertainty by a block bootstrap of the fit samples (residuals are correlated in time, so whole
   blocks of time are resampled), the delay by a linearised step per replicate, the other nonlinear
   parameters held, with a small-sample correction for the few blocks a run has
   (:func:`small_sample_stretch`);
4. judgement on the ``role: holdout`` runs (:func:`holdout_metrics`).

The ladder (:mod:`sim2real.sysid`) and the diagnosis (:mod:`sim2real.diagnosis`) both call this
module; it imports neither. It is one piece (~850 lines) because the fit, its consistent variant and
the bootstrap share the private ``_Problem`` (the design at given nonlinear parameters).
"""

from __future__ import annotations

import copy
import fnmatch
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from scipy import optimize, stats

from sim2real.dynamics import RigidBodyModel
from sim2real.effects import Effect, Signals, get_effect
from sim2real.effects.actuation_delay import MAX_DELAY, shift_prediction
from sim2real.errors import InputError
from sim2real.forked import map_forked
from sim2real.metrics import rmse

DELAY_STEP_S = 2e-4  # half-step of the central difference of the prediction in the delay (bootstrap)

DEFAULT_SETTINGS: dict[str, Any] = {
    "fit_rate_hz": 200.0,  # fit and judge on a decimated grid: the filtered signals are smooth
    "refine_max_samples": 2000,  # samples used by the nonlinear refinement
    "bootstrap_replicates": 200,
    "bootstrap_block_s": 1.0,
    "confidence": 0.95,
    "bootstrap_few_blocks_correction": True,  # small_sample_stretch; off only to measure what it corrects
    "seed": 0,
    # Weight of the entropic pull of link inertias towards CAD, x the noise floor's variance (sim2real.inertial):
    # "held_out" chooses it on held-out blocks of the fit runs (inertial.choose_prior_weight); a number fixes it.
    "inertia_regularization": "held_out",
    # Each joint's residual in units of its own noise floor (joint_weights); "none": plain N*m, to measure it.
    "joint_weighting": "noise_floor",
}

# A joint whose floor reads below this fraction of the arm's RMS floor is weighted as if it were there:
# an underestimated floor (a quiet sensor, a saturated log) must not let one joint take the whole fit.
MIN_FLOOR_FRACTION = 0.2
# The prior's weight (x the floor's variance) where no link inertia is fitted or the held-out choice fails.
INERTIA_PRIOR_FALLBACK = 1e-3


def joint_weights(noise_floor: np.ndarray, weighting: str = "noise_floor") -> np.ndarray:
    """Per-joint weights of the fit: each joint's residual in units of its own noise floor.

    Weighted least squares as Gautier and Poignet identify robots (each joint weighted by its error's
    standard deviation): a wrist whose torques are ten times smaller than the shoulder's then counts as
    much, in its own units, as the shoulder. Rescaled so that white noise at the floors gives the
    arm's RMS floor on every joint: the weighted data term stays in (N*m)^2, the scale of the
    inertial prior's weight. ``weighting="none"``: all ones (plain N*m).
    """
    floor = np.asarray(noise_floor, dtype=float).reshape(-1)
    if weighting == "none" or floor.size == 0 or not np.all(np.isfinite(floor)) or floor.max() <= 0:
        return np.ones(floor.size)
    rms = float(np.sqrt(np.mean(floor**2)))
    return rms / np.maximum(floor, MIN_FLOOR_FRACTION * rms)


def floor_units(residual: np.ndarray, noise_floor: np.ndarray) -> dict[str, Any]:
    """A residual's RMS in units of each joint's noise floor: per joint and over the arm (RMS of the ratios).

    1.0 is what white noise at the floor gives; the loop's decisions are taken in these units."""
    floor = np.asarray(noise_floor, dtype=float)
    rms = float(np.sqrt(np.mean(floor**2))) if floor.size else 0.0
    floor = np.maximum(floor, MIN_FLOOR_FRACTION * rms) if rms > 0 else np.ones_like(floor)
    ratio = np.sqrt(np.mean(np.asarray(residual, dtype=float) ** 2, axis=0)) / floor
    return {"overall": float(np.sqrt(np.mean(ratio**2))), "per_joint": [float(v) for v in ratio]}


# --------------------------------------------------------------------------------------------
# Data


def kept_segments(segments: Sequence[slice], rows: np.ndarray) -> list[slice]:
    """Run segments (slices of stacked rows) after keeping the sorted ``rows``: empty runs drop out."""
    kept = []
    start = 0
    for seg in segments:
        count = int(np.count_nonzero((rows >= seg.start) & (rows < seg.stop)))
        if count:
            kept.append(slice(start, start + count))
        start += count
    return kept


@dataclass
class TorqueData:
    """Runs stacked along time, on a uniform grid per run; ``segments`` are the run boundaries."""

    joint_names: list[str]
    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray  # judged torque
    segments: list[slice]
    run_names: list[str]
    torque_source: str  # "tau" (sensor) or "tau_cmd" (command)
    has_commands: bool
    noise_floor: np.ndarray  # per joint, RMS of torque no model can explain
    torque_sensor: str = "motor"  # where tau is measured: "motor" (before the drive's terms) or "link" (after)

    @property
    def n_samples(self) -> int:
        return len(self.time)

    def subset(self, rows: np.ndarray) -> TorqueData:
        """Rows of the stacked arrays (sorted); segments are rebuilt from the kept rows."""
        rows = np.sort(rows)
        segments = kept_segments(self.segments, rows)
        return TorqueData(
            self.joint_names, self.time[rows], self.q[rows], self.qd[rows], self.qdd[rows], self.tau[rows],
            segments, self.run_names, self.torque_source, self.has_commands, self.noise_floor, self.torque_sensor,
        )


def stack_runs(
    runs: Sequence[Mapping[str, Any]], joint_names: Sequence[str], fit_rate_hz: float | None = None
) -> TorqueData:
    """Stack runs given as mappings with time, q, qd, qdd, tau, torque_source, has_commands, noise_floor, name.

    Each run is decimated to at most ``fit_rate_hz`` (every k-th sample: the signals are already
    zero-phase filtered, the torque noise stays white). Noise floors combine as an RMS over samples.
    """
    if not runs:
        raise InputError(None, "runs", "no runs to fit or judge", "list runs with role fit and holdout in measurements.yaml")
    sources = {r["torque_source"] for r in runs}
    if len(sources) > 1:
        raise InputError(
            None, "runs", f"runs mix judged torque sources {sorted(sources)}",
            "give every run the same torque columns (all tau, or all tau_cmd only)",
        )
    sensors = {r.get("torque_sensor", "motor") for r in runs}
    if len(sensors) > 1:
        names = ", ".join(f"{r['name']} ({r.get('torque_sensor', 'motor')})" for r in runs)
        raise InputError(
            None, "runs", f"runs mix torque sensor positions: {names}",
            "fit runs of one arm's sensor together: every run's metadata `torque_sensor` the same (motor or link)",
        )
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("time", "q", "qd", "qdd", "tau")}
    segments, floors, counts, names = [], [], [], []
    start = 0
    for run in runs:
        time = np.asarray(run["time"], dtype=float)
        step = 1
        if fit_rate_hz and len(time) > 1:
            rate = 1.0 / float(np.median(np.diff(time)))
            step = max(1, int(round(rate / fit_rate_hz)))
        for key in parts:
            parts[key].append(np.asarray(run[key], dtype=float)[::step])
        count = len(parts["time"][-1])
        segments.append(slice(start, start + count))
        start += count
        floors.append(np.asarray(run["noise_floor"], dtype=float))
        counts.append(count)
        names.append(str(run["name"]))
    weights = np.asarray(counts, dtype=float)
    noise = np.sqrt(np.average(np.vstack(floors) ** 2, axis=0, weights=weights))
    return TorqueData(
        list(joint_names), *(np.concatenate(parts[k]) for k in ("time", "q", "qd", "qdd", "tau")),
        segments=segments, run_names=names, torque_source=sources.pop(),
        has_commands=all(bool(r.get("has_commands")) for r in runs), noise_floor=noise, torque_sensor=sensors.pop(),
    )


def run_from_prepared(prepared: Any, noise_floor: np.ndarray) -> dict[str, Any]:
    """A :class:`sim2real.measurements.PreparedRun` as the mapping :func:`stack_runs` takes."""
    return {
        "name": prepared.name, "time": prepared.time, "q": prepared.q, "qd": prepared.qd, "qdd": prepared.qdd,
        "tau": prepared.tau, "torque_source": prepared.torque_source,
        "has_commands": prepared.tau_cmd is not None, "noise_floor": noise_floor,
        "torque_sensor": getattr(prepared, "torque_sensor", "motor"),
    }


# --------------------------------------------------------------------------------------------
# Nominal model


def resolve_armature(patterns: Mapping[str, float] | None, joint_names: Sequence[str]) -> dict[str, float]:
    """robot.yaml ``armature`` (joint name or glob -> value; first match wins) per joint."""
    out: dict[str, float] = {}
    for joint in joint_names:
        for pattern, value in (patterns or {}).items():
            if fnmatch.fnmatchcase(joint, pattern):
                out[joint] = float(value)
                break
    return out


def _urdf_link_parameters(urdf_path: Path) -> dict[str, np.ndarray]:
    """Each URDF link's own dynamic parameters (Pinocchio order, about the link frame)."""
    out: dict[str, np.ndarray] = {}
    root = ET.parse(urdf_path).getroot()
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass = float(inertial.find("mass").get("value", "0"))
        origin = inertial.find("origin")
        xyz = np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
        rpy = np.array([float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
        el = inertial.find("inertia")
        get = lambda k: float(el.get(k, "0")) if el is not None else 0.0  # noqa: E731
        inertia = np.array(
            [[get("ixx"), get("ixy"), get("ixz")], [get("ixy"), get("iyy"), get("iyz")], [get("ixz"), get("iyz"), get("izz")]]
        )
        rotation = pin.rpy.rpyToMatrix(rpy)
        out[link.get("name")] = pin.Inertia(mass, xyz, rotation @ inertia @ rotation.T).toDynamicParameters()
    return out


def _collision_points(urdf_path: Path, link: ET.Element) -> np.ndarray | None:
    """Vertices of a link's collision meshes in the link frame (None when a mesh cannot be read)."""
    import trimesh

    from sim2real.urdf import resolve_package_uri

    points = []
    for collision in link.findall("collision"):
        mesh = collision.find("geometry/mesh")
        if mesh is None:
            return None  # primitives are rare on arms; without a mesh the body keeps the plain LMI
        try:
            loaded = trimesh.load(resolve_package_uri(mesh.get("filename", ""), source=urdf_path), force="mesh")
        except Exception:  # noqa: BLE001 - an unreadable mesh only drops the optional, stronger constraint
            return None
        scale = np.array([float(v) for v in mesh.get("scale", "1 1 1").split()])
        origin = collision.find("origin")
        xyz = np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
        rpy = np.array([float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
        points.append(np.asarray(loaded.vertices) * scale @ pin.rpy.rpyToMatrix(rpy).T + xyz)
    return np.vstack(points) if points else None


def _body_points(urdf_path: Path, body_links: Sequence[str]) -> list[np.ndarray | None]:
    """Collision-mesh vertices of each body's own link (link frame); None for the last body (it carries
    tools and payloads, so its mass may lie outside its meshes) and where no mesh can be read."""
    root = ET.parse(urdf_path).getroot()
    links = {link.get("name"): link for link in root.findall("link")}
    return [
        _collision_points(urdf_path, links[name]) if name in links and index < len(body_links) - 1 else None
        for index, name in enumerate(body_links)
    ]


def body_ellipsoids(
    urdf_path: Path, body_links: Sequence[str], points: Sequence[np.ndarray | None] | None = None
) -> list[np.ndarray | None]:
    """Bounding ellipsoid (``sim2real.inertial`` Q form) of each body's own link, from its collision meshes.

    The last body gets none: tools and payloads are mounted there, so its mass may lie outside its meshes.
    ``points``: the bodies' mesh vertices when already read (:func:`_body_points`).
    """
    from sim2real.inertial import bounding_ellipsoid

    points = _body_points(urdf_path, body_links) if points is None else points
    return [bounding_ellipsoid(p) if p is not None and len(p) >= 4 else None for p in points]


def body_hulls(
    urdf_path: Path, body_links: Sequence[str], points: Sequence[np.ndarray | None] | None = None
) -> list[np.ndarray | None]:
    """Convex hull of each body's own collision meshes as facet equations ``(k, 4)``: ``n . x + d <= 0``
    inside, ``n`` a unit outward normal (link frame). None where :func:`body_ellipsoids` has none (the
    last body) or the vertices span no volume. Qhull on a few hundred vertices: ~1 ms a body."""
    from scipy.spatial import ConvexHull, QhullError

    points = _body_points(urdf_path, body_links) if points is None else points
    out: list[np.ndarray | None] = []
    for p in points:
        try:
            out.append(np.asarray(ConvexHull(np.asarray(p, dtype=float)).equations) if p is not None and len(p) >= 4
                       else None)
        except (QhullError, ValueError):  # flat or degenerate meshes: no volume to be inside of
            out.append(None)
    return out


@dataclass
class NominalModel:
    """The URDF model the fit starts from and everything effects need to know about it."""

    dynamics: RigidBodyModel
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def joint_names(self) -> list[str]:
        return self.dynamics.joint_names


def load_nominal(
    urdf_path: str | Path,
    joint_names: Sequence[str],
    armature: Mapping[str, float] | None = None,
    flange: str | None = None,
) -> NominalModel:
    """Nominal model of the measured joints. ``armature``: robot.yaml patterns (the MJCF's armature)."""
    urdf_path = Path(urdf_path)
    dynamics = RigidBodyModel(urdf_path, joint_names, armature=resolve_armature(armature, joint_names))
    model = dynamics.model
    # Moving body of each joint (tree order) = the URDF child link of that joint.
    body_links = []
    for jid in range(1, model.njoints):
        links = [f.name for f in model.frames if f.parentJoint == jid and f.type == pin.FrameType.BODY]
        body_links.append(links[0] if links else model.names[jid])
    last_joint = model.njoints - 1
    flange_name = flange if flange and model.existFrame(flange) else body_links[-1]
    placement = model.frames[model.getFrameId(flange_name)].placement
    if model.frames[model.getFrameId(flange_name)].parentJoint != last_joint:
        raise InputError(
            urdf_path, f"flange '{flange_name}'", "is not carried by the last measured joint",
            "set robot.yaml flange to a link fixed to the last arm link",
        )
    points = _body_points(urdf_path, body_links)  # the meshes are read once for the ellipsoids and hulls
    info = {
        "damping": dynamics.damping.copy(),
        "friction": dynamics.friction.copy(),
        "armature": dynamics.armature.copy(),
        "inertial": dynamics.inertial_parameters(),
        "body_links": body_links,
        "n_bodies": model.njoints - 1,
        "last_link": body_links[-1],
        "flange": flange_name,
        "flange_rotation": np.asarray(placement.rotation).copy(),
        "flange_translation": np.asarray(placement.translation).copy(),
        "link_own_inertial": _urdf_link_parameters(urdf_path),
        "ellipsoids": body_ellipsoids(urdf_path, body_links, points),
        "hulls": body_hulls(urdf_path, body_links, points),  # where a COM may plausibly lie (link_inertia)
    }
    return NominalModel(dynamics, info)


def link_side(data: TorqueData) -> bool:
    """The judged torque is measured after the drive (a link-side sensor): it does not hold the drive's terms."""
    return data.torque_source == "tau" and data.torque_sensor == "link"


def make_signals(nominal: NominalModel, data: TorqueData) -> Signals:
    """The body link's signals: the judged torque predicted from the motion by the nominal model.

    A link-side sensor measures what the links need, without the drive's rotor inertia, damping and
    friction (those lie on the actuator link, :func:`sim2real.actuator.actuator_signals`).
    """
    dynamics = nominal.dynamics
    tau_nominal = dynamics.inverse_dynamics(data.q, data.qd, data.qdd)
    info = nominal.info
    if link_side(data):
        tau_nominal = tau_nominal - dynamics.drive_torque(data.qd, data.qdd)
        # A drive effect found here acts after the sensor: it starts from nothing, not from the URDF's value.
        info = {**info, **{key: np.zeros_like(np.asarray(info[key], dtype=float))
                           for key in ("damping", "friction", "armature") if key in info}}
    return Signals(
        joint_names=list(data.joint_names), time=data.time, q=data.q, qd=data.qd, qdd=data.qdd,
        tau_nominal=tau_nominal, segments=data.segments, tau=data.tau,
        regressor_fn=lambda: dynamics.regressor(data.q, data.qd, data.qdd), nominal=info,
    )


# --------------------------------------------------------------------------------------------
# Fit


@dataclass
class FitResult:
    effects: list[str]
    theta: dict[str, np.ndarray]  # linear coefficients per effect
    nonlinear: dict[str, np.ndarray]
    states: dict[str, dict[str, Any]]
    values: dict[str, Any]  # fitted values per effect (total, SI)
    intervals: dict[str, Any]
    fit_rmse: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    consistency: dict[str, Any] = field(default_factory=dict)
    unconstrained: FitResult | None = None  # the same rung without the physical constraints
    after_sensor: bool = False  # the body link behind a link-side sensor: drive effects are the part after it


class _Problem:
    """Columns and targets of one model on one data set, for a given nonlinear parameter vector."""

    def __init__(self, effects: list[Effect], signals: Signals, states: dict[str, dict[str, Any]],
                 weights: np.ndarray | None = None) -> None:
        self.effects = effects
        self.signals = signals
        self.states = states
        # Per-joint weights of the data term (joint_weights): the fit solves in units of each joint's floor.
        self.weights = np.ones(signals.n) if weights is None else np.asarray(weights, dtype=float)
        self.static_columns: dict[str, np.ndarray] = {}
        for effect in effects:
            if not effect.time_shift and not effect.nonlinear:
                self.static_columns[effect.name] = effect.columns(signals, states[effect.name], np.array([]))[0]
        self.nl_sizes = [len(e.nonlinear_init(signals)) for e in effects]

    def split_nonlinear(self, x: np.ndarray) -> dict[str, np.ndarray]:
        out, start = {}, 0
        for effect, size in zip(self.effects, self.nl_sizes, strict=True):
            out[effect.name] = np.asarray(x[start : start + size], dtype=float)
            start += size
        return out

    def delay(self, nonlinear: dict[str, np.ndarray]) -> float:
        """Time shift of the prediction: the command leads what it causes by the actuation delay."""
        for effect in self.effects:
            if effect.time_shift:
                delay = float(nonlinear[effect.name][0])
                return -delay if self.signals.forward else delay
        return 0.0

    def block(self, effect: Effect, nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """One effect's columns (N, n, k) at the given nonlinear parameters (before the time shift)."""
        cols = self.static_columns.get(effect.name)
        if cols is None:
            cols = effect.columns(self.signals, self.states[effect.name], nonlinear[effect.name])[0]
        if self.signals.forward and effect.drive:
            cols = -cols  # forward, the drive's terms are taken from the command before the link-side sensor
        return cols

    def shift(self, columns: np.ndarray, effects: Sequence[Effect], sizes: Sequence[int],
              nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """Columns as they enter the prediction: shifted by the delay, except a drive's on the actuator link
        (the command is delayed; the rotor inertia and friction act on the motion as it is)."""
        delay = self.delay(nonlinear)
        shifted = shift_prediction(columns, self.signals.time, self.signals.segments, delay)
        if delay != 0.0 and self.signals.forward:
            held = np.concatenate([np.full(size, effect.drive) for effect, size in zip(effects, sizes, strict=True)]
                                  or [np.zeros(0, dtype=bool)])
            shifted[:, :, held] = columns[:, :, held]
        return shifted

    def shifted_design(self, nonlinear: dict[str, np.ndarray]) -> tuple[np.ndarray, list[int]]:
        design, sizes = self.design(nonlinear)
        return self.shift(design, self.effects, sizes, nonlinear), sizes

    def base(self, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """The prediction without the linear columns: nominal and offsets, shifted; plus the unshifted term."""
        out = shift_prediction(self.signals.tau_nominal + self.offsets(theta), self.signals.time,
                               self.signals.segments, self.delay(nonlinear))
        return out if self.signals.unshifted is None else out + self.signals.unshifted

    def design(self, nonlinear: dict[str, np.ndarray]) -> tuple[np.ndarray, list[int]]:
        """Columns (N, n, p) at the given nonlinear parameters (before the time shift) and sizes."""
        blocks, sizes = [], []
        for effect in self.effects:
            if effect.time_shift:
                sizes.append(0)
                continue
            cols = self.block(effect, nonlinear)
            blocks.append(cols)
            sizes.append(cols.shape[2])
        n_samples, n = self.signals.q.shape
        design = np.concatenate(blocks, axis=2) if blocks else np.zeros((n_samples, n, 0))
        return design, sizes

    def offsets(self, theta: dict[str, np.ndarray]) -> np.ndarray:
        total = np.zeros_like(self.signals.tau_nominal)
        for effect in self.effects:
            if effect.name in theta:
                term = effect.offset(self.signals, self.states[effect.name], theta[effect.name])
                if term is not None:
                    total = total + term
        return total

    def predict(self, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray],
                shifted: tuple[np.ndarray, list[int]] | None = None) -> np.ndarray:
        """The prediction; ``shifted``: :meth:`shifted_design` at ``nonlinear`` when the caller has it already."""
        design, sizes = self.shifted_design(nonlinear) if shifted is None else shifted
        return self.base(theta, nonlinear) + design @ _flatten_theta(self.effects, theta, sizes)


def _flatten_theta(effects: list[Effect], theta: dict[str, np.ndarray], sizes: list[int]) -> np.ndarray:
    parts = [theta.get(e.name, np.zeros(s))[:s] for e, s in zip(effects, sizes, strict=True) if s]
    return np.concatenate(parts) if parts else np.zeros(0)


def _split_theta(effects: list[Effect], flat: np.ndarray, sizes: list[int]) -> dict[str, np.ndarray]:
    out, start = {}, 0
    for effect, size in zip(effects, sizes, strict=True):
        out[effect.name] = flat[start : start + size]
        start += size
    return out


def _solve_linear(design: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Minimum-norm least squares on unit-norm columns (collinear columns share, never blow up), each
    joint's rows multiplied by its weight (:func:`joint_weights`).

    Solved through the p x p Gram matrix (pseudo-inverse by SVD): the designs are tall
    (samples x joints rows, tens of columns), so this is many times faster than a QR of the design.
    """
    if design.shape[2] == 0:
        return np.zeros(0)
    if weights is not None:
        design, target = design * weights[None, :, None], target * weights[None, :]
    a = design.reshape(-1, design.shape[2])
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    a = a / scale
    coef = np.linalg.lstsq(a.T @ a, a.T @ target.reshape(-1), rcond=1e-12)[0]
    return coef / scale


def _linear_fit(problem: _Problem, tau: np.ndarray, nonlinear: dict[str, np.ndarray], iterations: int = 3):
    """Linear parameters at fixed nonlinear ones; offsets (payload inertia) by fixed-point iteration."""
    shifted, sizes = problem.shifted_design(nonlinear)
    has_offset = any(type(e).offset is not Effect.offset for e in problem.effects)
    theta: dict[str, np.ndarray] = {}
    for _ in range(iterations if has_offset else 1):
        flat = _solve_linear(shifted, tau - problem.base(theta, nonlinear), problem.weights)
        theta = _split_theta(problem.effects, flat, sizes)
    residual = tau - problem.predict(theta, nonlinear, (shifted, sizes))
    return theta, residual, sizes


def _refine_nonlinear(
    problem: _Problem, tau: np.ndarray, settings: Mapping[str, Any], fixed: Mapping[str, np.ndarray] | None = None,
    start: Mapping[str, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Nonlinear parameters by bounded least squares, the linear ones projected out.

    ``fixed``: nonlinear values of some effects to hold (e.g. the current model's, while the
    diagnosis tries a candidate on top of it); ``start``: values to start from but refine again (the
    previous rung's: a friction smoothing refined before the rotor inertia was in the model is refined
    again once it is); a delay given there starts from it instead of the grid.
    """
    signals = problem.signals
    fixed = dict(fixed or {})
    begin = {**dict(start or {}), **fixed}
    x0 = np.concatenate(
        [np.asarray(begin.get(e.name, e.nonlinear_init(signals)), dtype=float) for e in problem.effects] or [np.zeros(0)]
    )
    if x0.size == 0:
        return problem.split_nonlinear(x0)
    lower = np.concatenate([e.nonlinear_bounds(signals)[0] for e in problem.effects])
    upper = np.concatenate([e.nonlinear_bounds(signals)[1] for e in problem.effects])
    held = np.concatenate([np.full(s, e.name in fixed) for e, s in zip(problem.effects, problem.nl_sizes, strict=True)])
    # A previous value at its bound sits on a plateau (a sigmoid at its steepest is a sign function for every
    # sample: its slope no longer moves the residual), where the refinement cannot leave it: start that one
    # from its default instead.
    default = np.concatenate(
        [np.asarray(e.nonlinear_init(signals), dtype=float) for e in problem.effects] or [np.zeros(0)]
    )
    at_bound = ~held & ((x0 <= lower + 1e-9 * np.abs(lower)) | (x0 >= upper - 1e-9 * np.abs(upper)))
    x0 = np.where(at_bound & (lower < upper), default, x0)
    if held.all():
        return problem.split_nonlinear(x0)
    # The refinement runs on a subset of whole runs' samples (every k-th: keeps the time grid uniform).
    n_max = int(settings["refine_max_samples"])
    step = max(1, int(np.ceil(len(signals.time) / n_max)))
    rows = np.arange(0, len(signals.time), step)
    sub_signals = _subset_signals(signals, rows)
    sub = _Problem(problem.effects, sub_signals, problem.states, problem.weights)
    sub_tau = tau[rows]

    free = ~held

    def residual_full(x: np.ndarray) -> np.ndarray:
        return (_linear_fit(sub, sub_tau, sub.split_nonlinear(x), iterations=1)[1] * sub.weights).reshape(-1)

    def with_free(values: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = values
        return x

    # A delay has local minima at multiples of the signal's periods, and between samples where the
    # interpolation averages white noise away: start from a grid no coarser than the sampling step.
    offset = 0
    for effect, size in zip(problem.effects, problem.nl_sizes, strict=True):
        if effect.time_shift and effect.name not in begin:
            dt = float(np.median(np.diff(sub_signals.time))) if len(sub_signals.time) > 1 else MAX_DELAY
            grid = np.linspace(0.0, MAX_DELAY, max(41, int(round(MAX_DELAY / dt)) + 1))
            costs = []
            for d in grid:
                x = x0.copy()
                x[offset] = d
                costs.append(float(np.sum(residual_full(x) ** 2)))
            x0[offset] = grid[int(np.argmin(costs))]
        offset += size
    # Smoothing velocities span decades: optimise their logarithm.
    log_mask = np.concatenate(
        [np.asarray(e.nonlinear_log_scale(signals), dtype=bool) for e in problem.effects]
    )

    def to_z(x: np.ndarray) -> np.ndarray:
        z = x.copy()
        z[log_mask] = np.log(x[log_mask])
        return z

    z_lower, z_upper = to_z(lower)[free], to_z(upper)[free]
    z0 = np.clip(to_z(x0)[free], z_lower, z_upper)
    log_free = log_mask[free]

    def to_x_free(z: np.ndarray) -> np.ndarray:
        values = z.copy()
        values[log_free] = np.exp(z[log_free])
        return with_free(values)

    result = optimize.least_squares(
        lambda z: residual_full(to_x_free(z)), z0, bounds=(z_lower, z_upper), method="trf", x_scale="jac",
        diff_step=1e-3, max_nfev=60, xtol=1e-4, ftol=1e-6,
    )
    return problem.split_nonlinear(to_x_free(result.x))


def _subset_signals(signals: Signals, rows: np.ndarray) -> Signals:
    segments = kept_segments(signals.segments, rows)
    regressor = signals._regressor[rows] if signals._regressor is not None else None
    parent = signals
    return Signals(
        joint_names=signals.joint_names, time=signals.time[rows], q=signals.q[rows], qd=signals.qd[rows],
        qdd=signals.qdd[rows], tau_nominal=signals.tau_nominal[rows], segments=segments,
        tau=None if signals.tau is None else signals.tau[rows],
        regressor_fn=lambda: parent.regressor[rows], nominal=signals.nominal, forward=signals.forward,
        unshifted=None if signals.unshifted is None else signals.unshifted[rows], _regressor=regressor,
    )


def _values(effects: list[Effect], theta, nonlinear, signals: Signals, states) -> dict[str, Any]:
    """Structured values; with a gain (judged / applied torque), joint-local effects are rescaled to
    applied torque, except a sensor's own bias, which is added after its gain."""
    theta = dict(theta)
    scaling = next((e for e in effects if e.scales_judged and len(theta.get(e.name, []))), None)
    if scaling is not None and not signals.forward:  # forward, every term is already applied torque
        gain = 1.0 + theta[scaling.name]
        for effect in effects:
            if effect.joint_local and not effect.scales_judged and effect.name != "torque_bias" and len(theta[effect.name]):
                theta[effect.name] = theta[effect.name] / np.where(np.abs(gain) > 1e-6, gain, 1.0)
    return {e.name: e.values(theta[e.name], nonlinear[e.name], signals, states[e.name]) for e in effects}


def _block_bootstrap(
    problem: _Problem,
    tau: np.ndarray,
    nonlinear: dict[str, np.ndarray],
    theta: dict[str, np.ndarray],
    sizes: list[int],
    settings: Mapping[str, Any],
) -> list[tuple[dict[str, np.ndarray], dict[str, np.ndarray]]]:
    """(linear, nonlinear) parameters of block-bootstrap replicates (blocks of time resampled, all joints
    together). The linear ones are solved again on each resample; a delay moves by one Gauss-Newton step
    of the prediction linearised about the estimate, from the same resampled blocks, so it has an
    interval too. Other nonlinear parameters (friction smoothing) are held."""
    replicates = int(settings["bootstrap_replicates"])
    shift = next((e for e in problem.effects if e.time_shift), None)
    if replicates <= 0 or (sum(sizes) == 0 and shift is None):
        return []
    signals = problem.signals
    weights = problem.weights
    shifted, _ = problem.shifted_design(nonlinear)
    shifted = shifted * weights[None, :, None]  # the replicates solve the same weighted problem as the fit
    # Offsets (payload inertia) are held at the estimate: the replicates are linear solves.
    target = (tau - problem.base(theta, nonlinear)) * weights
    rows, p = shifted.shape[0] * shifted.shape[1], shifted.shape[2]
    scale = np.linalg.norm(shifted.reshape(rows, p), axis=0)
    scale[scale == 0] = 1.0
    if shift is not None:
        delay = float(nonlinear[shift.name][0])
        low, high = max(delay - DELAY_STEP_S, 0.0), delay + DELAY_STEP_S
        slope = weights * (problem.predict(theta, {**nonlinear, shift.name: np.array([high])})
                           - problem.predict(theta, {**nonlinear, shift.name: np.array([low])})) / (high - low)
        left = weights * (tau - problem.predict(theta, nonlinear))
    dt = float(np.median(np.diff(signals.time))) if len(signals.time) > 1 else 1.0
    block = max(2, int(round(float(settings["bootstrap_block_s"]) / dt)))
    # Gram matrices per block: a replicate is a sum of blocks, solved in p x p.
    grams, rhs, delay_grams, delay_rhs = [], [], [], []
    for seg in signals.segments:
        for start in range(seg.start, seg.stop, block):
            stop = min(start + block, seg.stop)
            a = (shifted[start:stop] / scale).reshape((stop - start) * shifted.shape[1], p)
            y = target[start:stop].reshape(-1)
            grams.append(a.T @ a)
            rhs.append(a.T @ y)
            if shift is not None:
                delay_grams.append(float(np.sum(slope[start:stop] ** 2)))
                delay_rhs.append(float(np.sum(slope[start:stop] * left[start:stop])))
    grams_arr, rhs_arr = np.asarray(grams), np.asarray(rhs)
    delay_grams_arr, delay_rhs_arr = np.asarray(delay_grams), np.asarray(delay_rhs)
    # Replicates are unconstrained solves; their spread around the full-sample solve is centred on the
    # estimate (which may be the consistent one), so intervals describe the estimate the rung reports.
    full = np.linalg.lstsq(grams_arr.sum(axis=0), rhs_arr.sum(axis=0), rcond=1e-12)[0] / scale
    estimate = _flatten_theta(problem.effects, theta, sizes)
    weights = np.trace(grams_arr, axis1=1, axis2=2) if p else delay_grams_arr
    stretch = (small_sample_stretch(weights, float(settings["confidence"]))
               if settings.get("bootstrap_few_blocks_correction", True) else 1.0)
    # The delay's steps are centred like the linear solves: the refinement ran on a subset of the samples.
    full_step = delay_rhs_arr.sum() / delay_grams_arr.sum() if shift is not None and delay_grams_arr.sum() > 0 else 0.0
    rng = np.random.default_rng(int(settings["seed"]))
    out = []
    for _ in range(replicates):
        pick = rng.integers(0, len(grams), size=len(grams))
        coef = np.linalg.lstsq(grams_arr[pick].sum(axis=0), rhs_arr[pick].sum(axis=0), rcond=1e-12)[0] / scale
        replicate_nonlinear = dict(nonlinear)
        if shift is not None and delay_grams_arr[pick].sum() > 0:
            step = delay_rhs_arr[pick].sum() / delay_grams_arr[pick].sum() - full_step
            replicate_nonlinear[shift.name] = np.array([float(np.clip(delay + stretch * step, 0.0, MAX_DELAY))])
        out.append((_split_theta(problem.effects, estimate + stretch * (coef - full), sizes), replicate_nonlinear))
    return out


def small_sample_stretch(block_weights: np.ndarray, confidence: float) -> float:
    """Factor on the replicates' deviations that makes percentile intervals from few blocks honest.

    A block bootstrap of B blocks sees the estimate's spread through B draws: its variance is short by
    (B - 1) / B, and the spread is itself estimated, so the interval needs Student's t quantile with
    B - 1 degrees of freedom instead of the normal one. Both matter at the usual 20-40 blocks:
    ``benchmarks/bench_sysid.py --case calibration`` counts how often the 95 % intervals of the
    per-joint friction hold the truth over independent lab draws, with and without the correction. Blocks of unequal information (segments cut
    short, partial last blocks) count by Kish's effective number (sum w)^2 / sum w^2 of their weights.
    """
    weights = np.asarray(block_weights, dtype=float)
    weights = weights[weights > 0]
    if weights.size < 2:
        return 1.0
    effective = float(weights.sum() ** 2 / np.sum(weights**2))
    if effective <= 1.0:
        return 1.0
    level = 0.5 + 0.5 * confidence
    return float(np.sqrt(effective / (effective - 1.0)) * stats.t.ppf(level, effective - 1.0) / stats.norm.ppf(level))


def _intervals(samples: list[Any], confidence: float) -> Any:
    """Percentile intervals of every number in a list of like-shaped structures."""
    first = samples[0]
    if isinstance(first, dict):
        return {k: _intervals([s[k] for s in samples], confidence) for k in first}
    if isinstance(first, list):
        return [_intervals([s[i] for s in samples], confidence) for i in range(len(first))]
    if isinstance(first, bool) or not isinstance(first, (int, float)):
        return None
    lo, hi = np.percentile(np.asarray(samples, dtype=float), [50 * (1 - confidence), 50 * (1 + confidence)])
    return [round(float(lo), 6), round(float(hi), 6)]


def _prune(tree: Any) -> Any:
    if isinstance(tree, dict):
        out = {k: _prune(v) for k, v in tree.items()}
        return {k: v for k, v in out.items() if v not in (None, {}, [])}
    return tree


def fit(
    effect_names: Sequence[str],
    nominal: NominalModel | None,
    data: TorqueData,
    settings: Mapping[str, Any] | None = None,
    signals: Signals | None = None,
    uncertainty: bool = True,
    consistency: bool = True,
    nonlinear_fixed: Mapping[str, np.ndarray] | None = None,
    nonlinear_start: Mapping[str, np.ndarray] | None = None,
) -> FitResult:
    """Fit the model ``nominal + effect_names`` on ``data`` (the fit runs).

    ``consistency``: solve the rung as one convex program (:mod:`sim2real.inertial`: link inertias
    physically consistent, friction/armature/payload mass >= 0) and keep the unconstrained fit beside
    it (``result.unconstrained``); ``uncertainty``: bootstrap intervals; ``nonlinear_fixed``: nonlinear
    parameters held (the diagnosis holds the current model's while it tries a candidate);
    ``nonlinear_start``: where the refinement starts (the ladder passes the previous rung's and refines
    every nonlinear parameter again, so a rung delivers at least the fall its candidate promised);
    ``signals``: what the judged torque is predicted from (default: the nominal model on ``data``;
    the actuator link passes its own and no nominal model).
    """
    settings = {**DEFAULT_SETTINGS, **(settings or {})}
    if signals is None:
        assert nominal is not None, "give the nominal model or the signals (the actuator link has no nominal model)"
        signals = make_signals(nominal, data)
    effects = [get_effect(name) for name in effect_names]
    notes = []
    for effect in effects:
        if effect.needs_commands and data.torque_source != "tau_cmd" and not signals.forward:
            notes.append(
                f"{effect.name}: the judged torque is measured ({data.torque_source}); a delay between command "
                "and applied torque does not show in it, so the torque-domain fit keeps it at 0"
            )
    states = {e.name: e.prepare(signals) for e in effects}
    weights = joint_weights(data.noise_floor, str(settings.get("joint_weighting", "noise_floor")))
    problem = _Problem(effects, signals, states, weights)
    nonlinear = _refine_nonlinear(problem, data.tau, settings, nonlinear_fixed, nonlinear_start)
    theta, residual, sizes = _linear_fit(problem, data.tau, nonlinear)
    unconstrained = FitResult(
        effects=list(effect_names), theta=theta, nonlinear=nonlinear, states=copy.deepcopy(states),
        values=_values(effects, theta, nonlinear, signals, states), intervals={},
        fit_rmse=rmse(residual, data.joint_names), notes=list(notes),
    )
    record: dict[str, Any] = {}
    if consistency:
        theta, residual, record = _consistent_fit(problem, data, nonlinear, theta, settings)
        notes.extend(record.pop("notes"))
    values = _values(effects, theta, nonlinear, signals, states)
    intervals: dict[str, Any] = {}
    if uncertainty:
        replicates = _block_bootstrap(problem, data.tau, nonlinear, theta, sizes, settings)
        if replicates:
            samples = [_values(effects, rep, rep_nonlinear, signals, states) for rep, rep_nonlinear in replicates]
            intervals = _prune(_intervals(samples, float(settings["confidence"])))
    return FitResult(
        effects=list(effect_names), theta=theta, nonlinear=nonlinear, states=states, values=values,
        intervals=intervals, fit_rmse=rmse(residual, data.joint_names), notes=notes, consistency=record,
        unconstrained=unconstrained if consistency else None, after_sensor=link_side(data) and not signals.forward,
    )


def fit_on_the_previous(
    effect_names: Sequence[str],
    nominal: NominalModel | None,
    fit_data: TorqueData,
    holdout_data: TorqueData,
    previous: Mapping[str, np.ndarray] | None,
    settings: Mapping[str, Any] | None = None,
    *,
    fit_signals: Signals | None = None,
    holdout_signals: Signals | None = None,
    uncertainty: bool = True,
    workers: int = 1,
) -> tuple[FitResult, np.ndarray, str]:
    """A model fitted on top of the previous one: (fit, holdout residual, how its nonlinear parameters were set).

    Two ways to carry the previous model's nonlinear parameters (friction slopes and offsets, a delay):
    refine them all again from there, so that a smoothing refined before the rotor inertia was in the
    model can move once it is, or hold them, so that a sharp sigmoid cannot wander off to absorb what
    the new effect should explain. The fit runs alone cannot tell which generalises (the refinement
    always lowers the fit residual); the one whose holdout residual is smaller, each joint in units of
    its own floor, is kept. The diagnosis and the ladder use this same rule, so a rung delivers what
    its diagnosis promised. ``"refined"`` also when there is nothing to hold. ``workers``: with two, both
    ways are fitted side by side (:func:`sim2real.forked.map_forked`).
    """
    previous = {k: v for k, v in (previous or {}).items() if np.size(v)}
    if fit_signals is None:
        assert nominal is not None
        fit_signals = make_signals(nominal, fit_data)
    if holdout_signals is None:
        assert nominal is not None
        holdout_signals = make_signals(nominal, holdout_data)
    weights = joint_weights(holdout_data.noise_floor, str({**DEFAULT_SETTINGS, **(settings or {})}["joint_weighting"]))

    def judged(result: FitResult) -> tuple[np.ndarray, float]:
        _, residual = holdout_metrics(result, nominal, holdout_data, holdout_signals)
        return residual, float(np.sum((residual * weights) ** 2))

    ways = [{"uncertainty": uncertainty, "nonlinear_start": previous}]
    if previous:
        ways.append({"uncertainty": False, "nonlinear_fixed": previous})
    fits = map_forked(_fit_way, ways, workers, {"effect_names": effect_names, "nominal": nominal, "data": fit_data,
                                                "settings": settings, "signals": fit_signals})
    refined = fits[0]
    residual, score = judged(refined)
    if not previous:
        return refined, residual, "refined"
    held = fits[1]
    held_residual, held_score = judged(held)
    if held_score >= score:
        return refined, residual, "refined"
    if uncertainty:
        held = fit(effect_names, nominal, fit_data, settings, signals=fit_signals, uncertainty=True,
                   nonlinear_fixed=previous)
    return held, held_residual, "held"


def _fit_way(way: Mapping[str, Any], **inputs: Any) -> FitResult:
    """:func:`fit` with one way of carrying the previous nonlinear parameters (:func:`fit_on_the_previous`)."""
    return fit(**inputs, **way)


def _consistent_fit(
    problem: _Problem, data: TorqueData, nonlinear: dict[str, np.ndarray], theta_free: dict[str, np.ndarray],
    settings: Mapping[str, Any],
) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, Any]]:
    """The rung's linear coefficients under the physical constraints; (theta, fit residual, record).

    Link inertias enter as full per-body corrections (the regressor's columns), every other effect
    with its own columns and lower bounds. Offsets that are not linear (a payload's own inertia) are
    held at the current estimate and updated by fixed-point iteration, as in the unconstrained fit.
    """
    from sim2real.effects.link_inertia import correction_anchors
    from sim2real.inertial import (
        InertialBlock,
        InfeasibleFit,
        choose_prior_weight,
        physically_consistent,
        pseudo_inertia,
        solve_consistent,
    )

    signals = problem.signals
    blocks, lower, inertial = [], [], None
    start = 0
    for effect in problem.effects:
        if effect.time_shift:
            continue
        if effect.name == "link_inertia":
            cols = signals.regressor
            anchors = correction_anchors(signals.nominal)
            # A body's mass must lie inside its meshes' ellipsoid where the CAD link itself does.
            ellipsoids = [
                q if q is not None and float(np.trace(pseudo_inertia(a) @ q)) >= 0 else None
                for a, q in zip(anchors, signals.nominal.get("ellipsoids") or [None] * len(anchors), strict=True)
            ]
            inertial = InertialBlock(slice(start, start + cols.shape[2]), anchors, ellipsoids)
            lower.append(np.full(cols.shape[2], -np.inf))
            problem.states[effect.name]["null_offset"] = np.zeros(cols.shape[2])
        else:
            cols = problem.block(effect, nonlinear)
            lower.append(np.asarray(effect.theta_lower(signals, cols.shape[2]), dtype=float))
        blocks.append((effect, slice(start, start + cols.shape[2]), cols))
        start += cols.shape[2]
    free_residual = data.tau - problem.predict(theta_free, nonlinear)
    record: dict[str, Any] = {"notes": []}
    if not blocks:
        return theta_free, free_residual, record
    shifted = problem.shift(np.concatenate([b[2] for b in blocks], axis=2), [b[0] for b in blocks],
                            [b[2].shape[2] for b in blocks], nonlinear)
    bounds = np.concatenate(lower)
    floor = float(np.mean(np.asarray(data.noise_floor, dtype=float) ** 2))
    relative = settings["inertia_regularization"]
    if relative == "held_out":
        relative = INERTIA_PRIOR_FALLBACK
        if inertial is not None:
            try:
                choice = choose_prior_weight(shifted * problem.weights[None, :, None],
                                             (data.tau - problem.base({}, nonlinear)) * problem.weights,
                                             bounds, inertial, max(floor, 1e-12))
                relative = choice.weight
                record["inertia_prior"] = {
                    "weight": choice.weight, "grid": choice.grid, "scores": choice.scores,
                    "chosen_by": f"cross-validation on {choice.blocks} held-out blocks of the fit runs (the strongest "
                    "pull towards CAD within 1% of the best held-out error; weights are fractions of the noise "
                    "floor's variance, scores held-out RMS in N*m, each joint weighted by its floor)"}
            except InfeasibleFit:
                pass  # the rung's own solve below says what failed
    elif inertial is not None:
        record["inertia_prior"] = {"weight": float(relative), "chosen_by": "the model.yaml setting "
                                   "fit.inertia_regularization (a fraction of the noise floor's variance)"}
    weight = float(relative) * max(floor, 1e-12)
    has_offset = any(type(e).offset is not Effect.offset and e.name != "link_inertia" for e in problem.effects)
    theta: dict[str, np.ndarray] = {}
    solve_time = 0.0
    try:
        for _ in range(3 if has_offset else 1):
            solution = solve_consistent(shifted * problem.weights[None, :, None],
                                        (data.tau - problem.base(theta, nonlinear)) * problem.weights,
                                        bounds, inertial, weight)
            solve_time += solution.solve_time_s
            for effect, cols, _ in blocks:
                coefficients = solution.coefficients[cols]
                if effect.name == "link_inertia":
                    coefficients = effect.set_correction(problem.states[effect.name], coefficients)
                theta[effect.name] = coefficients
        for effect in problem.effects:
            theta.setdefault(effect.name, np.zeros(0))  # a time shift has no linear coefficients
    except InfeasibleFit as exc:
        record["status"] = "infeasible"
        record["notes"].append(
            f"physical consistency: {exc}; the rung keeps the UNCONSTRAINED fit, which may be non-physical. "
            "Check the torque signs and units of the runs and the URDF's inertials"
        )
        return theta_free, free_residual, record
    residual = data.tau - problem.predict(theta, nonlinear)
    record.update({"status": solution.status, "solve_time_s": solve_time})
    free_physical = _physical(problem, theta_free, signals)
    record["unconstrained_physical"] = free_physical
    # Compared as fitted: in the weighted units of the data term, where white noise at the floors is the arm's floor.
    fit_now = float(np.sqrt(np.mean((residual * problem.weights) ** 2)))
    fit_free = float(np.sqrt(np.mean((free_residual * problem.weights) ** 2)))
    noise = float(np.sqrt(floor))
    if not free_physical and fit_now > 1.1 * fit_free and fit_now - fit_free > 0.1 * noise:
        # The data pull the model out of the physical set: say so, never hide it behind the nominal model.
        record["contradiction"] = True
        record["notes"].append(
            f"physical consistency: the data contradict a physical model with these effects: the unconstrained fit "
            f"needs non-physical values ({_violations(problem, theta_free, signals)}) and fits the fit runs to "
            f"{fit_free:.3g} against {fit_now:.3g} for the best physical fit (RMS in N*m, each joint weighted by its "
            "noise floor). An effect is missing, or the "
            "torque columns' sign or units are wrong"
        )
    if inertial is not None:
        delta = problem.states["link_inertia"]["basis"] @ theta["link_inertia"] + problem.states["link_inertia"]["null_offset"]
        assert physically_consistent(inertial.anchors.reshape(-1) + delta)
    return theta, residual, record


def _physical(problem: _Problem, theta: dict[str, np.ndarray], signals: Signals) -> bool:
    """Does a solution satisfy every constraint of the consistent fit?"""
    return not _violations(problem, theta, signals)


def _violations(problem: _Problem, theta: dict[str, np.ndarray], signals: Signals) -> str:
    """What is non-physical in a solution, in words ('' when nothing)."""
    from sim2real.effects.link_inertia import correction_anchors
    from sim2real.inertial import min_eigenvalues

    found = []
    for effect in problem.effects:
        coefficients = np.asarray(theta.get(effect.name, []), dtype=float)
        if effect.time_shift or not coefficients.size:
            continue
        if effect.name == "link_inertia":
            state = problem.states[effect.name]
            anchors = correction_anchors(signals.nominal)
            eig = min_eigenvalues(anchors.reshape(-1) + state["basis"] @ coefficients + state["null_offset"])
            bad = [signals.nominal["body_links"][b] for b in np.flatnonzero(eig <= 0)]
            if bad:
                found.append(f"link_inertia: non-physical inertia of {', '.join(bad)}")
            continue
        low = effect.theta_lower(signals, coefficients.size)
        below = np.flatnonzero(coefficients < low - 1e-9)
        if below.size:
            found.append(f"{effect.name}: {below.size} value(s) below their physical bound")
    return "; ".join(found)


def predict(
    result: FitResult, nominal: NominalModel | None, data: TorqueData, signals: Signals | None = None
) -> np.ndarray:
    """Judged torque the fitted model predicts on ``data`` (e.g. the holdout runs).

    ``nominal`` may be None when ``signals`` are given (the actuator link, :mod:`sim2real.actuator`)."""
    if signals is None:
        assert nominal is not None
        signals = make_signals(nominal, data)
    effects = [get_effect(name) for name in result.effects]
    problem = _Problem(effects, signals, result.states)
    return problem.predict(result.theta, result.nonlinear)


def holdout_metrics(result: FitResult, nominal: NominalModel | None, data: TorqueData, signals: Signals | None = None):
    """(metrics, residual) on the holdout data: ``{"torque_rmse": rmse shape}``."""
    residual = data.tau - predict(result, nominal, data, signals)
    return {"torque_rmse": rmse(residual, data.joint_names)}, residual


# --------------------------------------------------------------------------------------------
# Ladder, documents and the file-level entry point



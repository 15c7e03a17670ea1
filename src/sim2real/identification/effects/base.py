"""The shape every effect module shares.

An effect is a physical phenomenon the nominal rigid-body model lacks. Each one says
- its ``name`` (the vocabulary of configs/{robot}/model.yaml and of the lab),
- its parameters (:class:`ParameterSpec`: per joint or global, unit, bounds),
- how it enters inverse dynamics: regressor columns that are linear in its parameters
  (:meth:`Effect.columns`), optionally depending on a few nonlinear parameters that the fit
  refines (``nonlinear``), or a time shift of the whole prediction (``time_shift``),
- how it is written into MJCF (:meth:`Effect.apply_to_spec`, MjSpec edits) and into the
  calibration YAML the Xacro reads (:meth:`Effect.calibration`),
- its residual signature (:meth:`Effect.evidence`): per-joint statistics of a residual that
  show the effect is there,
- its ``side`` (:class:`sim2real.identification.records.Side`): ``DRIVE`` (between the commanded torque and the
  torque applied to the joint: a delay, a motor gain, a command bias) or ``BODY`` (between the applied torque and
  the motion: friction, inertias, payload; and the torque sensor's own gain and bias, which measure that torque).
  When runs log both the measured and the commanded torque, each side is fitted and judged on its
  own (:mod:`sim2real.identification.sides`). A ``drive`` effect (rotor inertia, joint friction and damping) sits
  in the drive between the motor and the link: on the body side behind a motor-side sensor, on the
  drive side in front of a link-side one (:func:`sim2real.identification.sides.effect_side`).

Fitted values always live in one structure, ``{param_name: {joint: value}}`` for per-joint
parameters and ``{param_name: value}`` for global ones, in SI units, as *total* values (the
nominal URDF value plus what the fit added), so they can be written into assets directly.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from sim2real.identification.records import Side


@dataclass(frozen=True)
class ParameterSpec:
    name: str
    unit: str
    lower: float
    upper: float
    per_joint: bool = True
    description: str = ""


@dataclass(frozen=True)
class ColumnLabel:
    """What one regressor column estimates: a parameter, on a joint (None: global)."""

    param: str
    joint: str | None = None


@dataclass
class Signals:
    """Samples and nominal-model quantities an effect needs (all arrays are (N, n) unless noted).

    ``segments`` are the run boundaries (a time shift never crosses them).
    ``regressor`` is Pinocchio's joint-torque regressor (N, n, 10*bodies), computed on demand.
    ``forward``: the judged torque is predicted forward in time from the command that caused it (the
    drive side: measured from commanded torque, ``tau_nominal`` holds the command); otherwise it is
    predicted from the motion through the model (the judged torque is then the cause of the motion).
    """

    joint_names: list[str]
    time: np.ndarray  # (N,)
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau_nominal: np.ndarray  # nominal model prediction of the judged torque
    segments: list[slice]
    tau: np.ndarray | None = None  # the judged torque (measured, else commanded)
    regressor_fn: Any = None  # callable () -> (N, n, P)
    nominal: dict[str, Any] = field(default_factory=dict)  # damping, friction, armature, inertial, bodies, ...
    forward: bool = False
    # Forward, behind a link-side sensor: the nominal drive terms (minus armature * qdd + ...), which act
    # on the motion now, so the delay that shifts the command does not shift them.
    unshifted: np.ndarray | None = None
    _regressor: np.ndarray | None = None
    # callable () -> (N, n, 3): the nominal model's generalized gravity under unit gravity along the base's x, y, z
    # (sim2real.assets.dynamics.RigidBodyModel.unit_gravity), computed on demand (None: not known to these signals)
    gravity_fn: Any = None
    _gravity: np.ndarray | None = None
    # What effects compute once per signals (e.g. link_inertia's basis), keyed by the effect; never compared
    # or digested (a leading underscore: sim2real.cache leaves it out).
    _memo: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @property
    def n(self) -> int:
        return len(self.joint_names)

    @property
    def regressor(self) -> np.ndarray:
        if self._regressor is None:
            self._regressor = np.asarray(self.regressor_fn())
        return self._regressor

    @property
    def unit_gravity(self) -> np.ndarray:
        """(N, n, 3): :attr:`gravity_fn`'s, computed once."""
        if self._gravity is None:
            if self.gravity_fn is None:
                raise ValueError("these signals carry no unit gravity (make_signals gives it)")
            self._gravity = np.asarray(self.gravity_fn())
        return self._gravity


def diagonal_columns(values: np.ndarray) -> np.ndarray:
    """(N, n) per-joint feature -> (N, n, n) columns: column j acts only on joint j."""
    n_samples, n = values.shape
    cols = np.zeros((n_samples, n, n))
    idx = np.arange(n)
    cols[:, idx, idx] = values
    return cols


def correlation_per_joint(residual: np.ndarray, feature: np.ndarray) -> np.ndarray:
    """Pearson correlation of residual and feature, per joint (0 where either is constant)."""
    r = residual - residual.mean(axis=0)
    f = feature - feature.mean(axis=0)
    denom = np.sqrt((r**2).sum(axis=0) * (f**2).sum(axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(denom > 0, (r * f).sum(axis=0) / denom, 0.0)
    return out


def explained_per_joint(residual: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Fraction of each joint's residual energy that a least-squares fit on ``columns`` removes.

    ``columns`` is (N, n, k); only joint j's rows are used for joint j (a per-joint R^2).
    """
    out = np.zeros(residual.shape[1])
    for j in range(residual.shape[1]):
        a = columns[:, j, :]
        keep = np.abs(a).sum(axis=0) > 0
        if not keep.any():
            continue
        a = a[:, keep]
        y = residual[:, j]
        coef = np.linalg.lstsq(a.T @ a, a.T @ y, rcond=1e-12)[0]
        sse0 = float(y @ y)
        if sse0 > 0:
            out[j] = max(0.0, 1.0 - float(np.sum((y - a @ coef) ** 2)) / sse0)
    return out


class Replicates(list):
    """A value of a value tree that has one number per bootstrap replicate (:attr:`Effect.values_stacked`)."""


def per_joint_dict(joint_names: list[str], values: np.ndarray, digits: int = 4) -> dict[str, Any]:
    """``{joint: value}`` rounded to ``digits``; ``values`` (replicates, n) gives ``{joint: Replicates}``."""
    values = np.asarray(values)
    if values.ndim == 2:
        return {j: Replicates([round(v, digits) for v in column])
                for j, column in zip(joint_names, values.T.tolist(), strict=True)}
    return {j: round(float(v), digits) for j, v in zip(joint_names, values, strict=True)}


def identified_actuators(context: dict[str, Any]) -> list[tuple[str, str]]:
    """(joint, actuator) of the MJCF's actuators that drive an identified joint (``context["joints"]``; None: every
    one), by joint name: what an effect fitted on those joints may write (a gripper's drive was not fitted)."""
    identified = context.get("joints")
    return [(joint, actuator) for joint, actuator in sorted(context.get("actuators", {}).items())
            if identified is None or joint in identified]



@dataclass(frozen=True)
class Signature:
    """What :meth:`Effect.evidence` finds of an effect in a residual: the effect's :attr:`Effect.signature`
    (``description``), the statistic computed, its value per joint and, for a lag, the lag that best aligns the
    torques per joint (``lag_s``; None for another effect). The diagnosis's candidate row
    (:class:`sim2real.identification.diagnosis.result.CandidateEvidence`) writes it into its document."""

    description: str
    statistic: str
    per_joint: Mapping[str, float]
    lag_s: Mapping[str, float] | None = None


class Effect:
    """Base class; one subclass per module in this package."""

    name: ClassVar[str]
    summary: ClassVar[str]
    signature: ClassVar[str]  # in words: what the residual looks like when this effect is missing
    parameters: ClassVar[tuple[ParameterSpec, ...]] = ()
    nonlinear: ClassVar[tuple[ParameterSpec, ...]] = ()  # refined by nonlinear least squares
    time_shift: ClassVar[bool] = False  # a lag of the whole prediction instead of columns (effects.timing)
    lowpass: ClassVar[bool] = False  # a time shift shaped as a first-order lag (its time constant), not a delay
    side: ClassVar[Side] = Side.BODY  # DRIVE: command -> applied torque; BODY: applied torque -> motion
    drive: ClassVar[bool] = False  # in the drive (motor to link): its side follows the torque sensor's placement
    needs_commands: ClassVar[bool] = False  # only observable when the judged torque is the command
    sensor_side: ClassVar[bool] = False  # an error of the torque sensor: meaningless on runs without one
    scales_judged: ClassVar[bool] = False  # its coefficient scales the whole judged torque (a gain)
    # its columns read the nominal model's torque (Signals.tau_nominal), which a design computes only for those
    needs_model_torque: ClassVar[bool] = False
    joint_local: ClassVar[bool] = True  # each parameter acts on its own joint only
    # a lag of the judged torque: the diagnosis fits it only where a lag, linearised, could matter
    # (sim2real.identification.fitting.lag_score)
    lag_screened: ClassVar[bool] = False
    # values() also takes theta stacked over the bootstrap's replicates (replicates, size) with nonlinear
    # parameters shared by all of them, and gives Replicates where a value depends on theta, each number the one
    # it gives the replicate alone (tests/test_sysid.py holds every such effect to it)
    values_stacked: ClassVar[bool] = False
    in_urdf: ClassVar[bool] = False  # the calibrated URDF holds it (so the MJCF built from it does too)
    # the excitation design makes its columns identifiable (sim2real.excitation.config.identification_effects); a
    # position ripple's are harmonics of a period no design knows beforehand: any motion over a few of them will do
    in_design: ClassVar[bool] = True
    # Estimated on every run itself, holdout runs included, instead of fitted on the fit runs and carried over (a
    # sensor's drift within each run): projected out of the judged torque and of every column
    # (sim2real.identification.fitting.problem._Problem); never a candidate, since no held-out run can judge it.
    per_run: ClassVar[bool] = False
    # In the model of every side, whatever its place (the judged torque of each side is the sensor's reading).
    every_side: ClassVar[bool] = False

    @property
    def per_joint_line(self) -> bool:
        """Whether a model.yaml line may keep it on some joints (``- coulomb_friction: {joints: [...]}``): each of its
        linear parameters is a joint's own and acts on that joint alone, so its columns on the other joints' rows can
        be left out (a friction, a rotor inertia, a sensor's gain on a joint); a link's inertia, a payload, a mount or
        a lag acts on every joint at once."""
        return bool(self.parameters) and all(p.per_joint for p in self.parameters) and self.joint_local \
            and not self.time_shift and not self.per_run

    # --- inverse dynamics -------------------------------------------------------------------
    def prediction_shift(self, delay: float, forward: bool) -> float:
        """A time shift's move of the prediction (s; the prediction at t is the model at t + the move): the command
        leads what it causes by an actuation delay, forward (from the command) and against the motion alike."""
        return -delay if forward else delay

    def prediction_lag(self, time_constant: float, forward: bool) -> float:
        """A first-order lag's time constant on the prediction (s; positive: the model through a low-pass, negative:
        through its inverse): forward, the applied torque is the command through the drive's low-pass; against the
        motion, the command is what the low-pass turns into the applied torque."""
        return time_constant if forward else -time_constant

    def prepare(self, signals: Signals) -> dict[str, Any]:
        """Data-dependent state computed once on the fit data (e.g. an identifiable basis)."""
        return {}

    def nonlinear_init(self, signals: Signals) -> np.ndarray:
        return np.array([])

    def nonlinear_bounds(self, signals: Signals) -> tuple[np.ndarray, np.ndarray]:
        return np.array([]), np.array([])

    # A start searched from what the model without the effect leaves (its nonlinear parameters have a local minimum
    # at many places: a period at every other one): :meth:`search_start`, called by the refinement.
    searched: ClassVar[bool] = False

    def search_start(self, signals: Signals, residual: np.ndarray) -> np.ndarray:
        """Where the refinement starts, given the residual (N, n) of the model without this effect."""
        return self.nonlinear_init(signals)

    def nonlinear_log_scale(self, signals: Signals) -> np.ndarray:
        """Which nonlinear values the refinement optimises in log scale (bool, same length as
        :meth:`nonlinear_init`): positive values spanning decades (a smoothing velocity, a slope)."""
        return np.zeros(len(self.nonlinear_init(signals)), dtype=bool)

    def columns(
        self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray
    ) -> tuple[np.ndarray, list[ColumnLabel]]:
        """Regressor columns (N, n, k), linear in this effect's parameters, and their labels."""
        return np.zeros((len(signals.time), signals.n, 0)), []

    def theta_lower(self, signals: Signals, size: int) -> np.ndarray:
        """Lower bounds of the fitted coefficients (the consistent fit's constraints); -inf where none."""
        return np.full(size, -np.inf)

    def offset(self, signals: Signals, state: dict[str, Any], theta: np.ndarray) -> np.ndarray | None:
        """Torque term not linear in the parameters, evaluated at the current estimate (or None)."""
        return None

    def values(
        self, theta: np.ndarray, nonlinear: np.ndarray, signals: Signals, state: dict[str, Any]
    ) -> dict[str, Any]:
        """Fitted parameters in the structured, total-value form described in the module docstring."""
        raise NotImplementedError

    # --- residual signature -----------------------------------------------------------------
    def evidence(self, residual: np.ndarray, signals: Signals) -> Signature:
        raise NotImplementedError

    # --- assets -----------------------------------------------------------------------------
    def apply_to_spec(self, spec: Any, values: dict[str, Any], context: dict[str, Any]) -> None:
        """Write the values into a MuJoCo MjSpec (in place)."""

    def calibration(self, values: dict[str, Any], calibration: dict[str, Any]) -> None:
        """Write the values URDF can hold into the calibration dict consumed by the Xacro (in place)."""


class DiagonalEffect(Effect):
    """A per-joint term ``value_j * feature_j`` whose total value (the nominal's, from the URDF or the MJCF, plus
    the fit's) is never negative: rotor inertia on ``qdd``, viscous friction on ``qd``. A subclass names its
    parameter (:attr:`parameters`, whose name is also the nominal model's key) and its :attr:`feature`."""

    drive = True
    feature: ClassVar[str]  # the Signals array the term is proportional to: "qd" or "qdd"
    values_stacked = True

    @property
    def key(self) -> str:
        return self.parameters[0].name

    def _nominal(self, signals: Signals) -> np.ndarray:
        return np.asarray(signals.nominal.get(self.key, np.zeros(signals.n)), dtype=float)

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        return diagonal_columns(getattr(signals, self.feature)), [ColumnLabel(self.key, j) for j in signals.joint_names]

    def theta_lower(self, signals, size):
        return -self._nominal(signals)  # the total (nominal + fitted) is never negative

    def values(self, theta, nonlinear, signals, state):
        return {self.key: per_joint_dict(signals.joint_names, self._nominal(signals) + theta, 6)}

    def evidence(self, residual, signals):
        feature = getattr(signals, self.feature)
        return Signature(
            description=self.signature,
            statistic=f"correlation of residual with {self.feature}",
            per_joint=per_joint_dict(signals.joint_names, correlation_per_joint(residual, feature), 3),
        )

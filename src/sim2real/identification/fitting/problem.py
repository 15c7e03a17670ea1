"""One model on one data set: the design at given nonlinear parameters (``_Problem``) and the fitted values
(:class:`FitResult`). The linear solve is :mod:`~sim2real.identification.fitting.linear`'s, the refinement of the
nonlinear parameters :mod:`~sim2real.identification.fitting.refine`'s."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim2real import blas
from sim2real.identification import inertial
from sim2real.identification.effects import Effect, Signals
from sim2real.identification.effects.sensor_drift import remove_runs, run_bases
from sim2real.identification.effects.timing import retime
from sim2real.identification.fitting.data import kept_segments


PREDICT_CHUNK_BYTES = 32 * 2**20  # the design's rows put together at once by _Problem.predict


# An effect's columns at its last nonlinear parameters are kept up to this size (the fit, its consistent variant,
# the predictions and the bootstrap ask for them in turn); a long log's larger blocks are computed again instead
# of staying alive beside the arrays of the next steps.
KEPT_BLOCK_BYTES = 16 * 2**20


@dataclass
class FitResult:
    effects: list[str]
    theta: dict[str, np.ndarray]  # linear coefficients per effect
    nonlinear: dict[str, np.ndarray]
    states: dict[str, dict[str, Any]]
    values: dict[str, Any]  # fitted values per effect (total, SI)
    intervals: dict[str, Any]
    fit_rmse: dict[str, Any]
    notes: list[dict[str, Any]] = field(default_factory=list)  # Note documents (sim2real.identification.records)
    consistency: dict[str, Any] = field(default_factory=dict)
    unconstrained: FitResult | None = None  # the same rung without the physical constraints
    after_sensor: bool = False  # the body side behind a link-side sensor: drive effects are the part after it
    effect_joints: dict[str, list[str]] = field(default_factory=dict)  # the lines kept on some joints: {effect: joints}


class _Problem:
    """Columns and targets of one model on one data set, for a given nonlinear parameter vector."""

    def __init__(self, effects: list[Effect], signals: Signals, states: dict[str, dict[str, Any]],
                 weights: np.ndarray | None = None, reuse_design: bool = False,
                 still_joints: Sequence[str] = (), effect_joints: Mapping[str, Sequence[str]] | None = None) -> None:
        self.effects = effects
        self.signals = signals
        self.states = states
        # The joints that barely move in the fit runs (sim2real.measurements.motion): their drives' own parameters
        # (friction, rotor inertia) are held at the nominal model's, their columns zero on those joints' rows.
        self.still_joints = tuple(j for j in signals.joint_names if j in set(still_joints))
        self.still_rows = np.array([signals.joint_names.index(j) for j in self.still_joints], dtype=int)
        # The lines model.yaml keeps on some joints (- coulomb_friction: {joints: [...]}): the effect is absent on
        # the others, its columns zero on their rows.
        self.effect_joints = {name: tuple(joints) for name, joints in (effect_joints or {}).items()}
        # Per-joint weights of the data term (joint_weights): the fit solves in units of each joint's floor.
        self.weights = np.ones(signals.n) if weights is None else np.asarray(weights, dtype=float)
        # An effect estimated on every run itself (a sensor's drift, Effect.per_run): each run's polynomials in its
        # time, projected out of every column and of the judged torque (base), so that a fit solves for the rest
        # with them profiled out and a prediction on any runs holds their own.
        self.run_bases = (run_bases(signals.time, signals.segments)
                          if any(effect.per_run for effect in effects) and signals.tau is not None else None)
        # ... on the joints its line is kept on (None: every joint)
        drifting = [self.effect_joints[e.name] for e in effects if e.per_run and e.name in self.effect_joints]
        self.drift_rows = (np.array([k for k, j in enumerate(signals.joint_names) if j in set(drifting[0])], dtype=int)
                           if drifting else None)
        self.static_columns: dict[str, np.ndarray] = {}
        for effect in effects:
            if not effect.time_shift and not effect.nonlinear:
                self.static_columns[effect.name] = self.without_still(effect, self.per_run_removed(
                    effect.columns(signals, states[effect.name], np.array([]))[0]))
        self.nl_sizes = [len(e.nonlinear_init(signals)) for e in effects]
        # reuse_design: each design() writes the moving columns into the last one's array, the static ones stay
        # (the refinement asks for hundreds; a caller must be done with one design before it asks for the next)
        self._reused: tuple[np.ndarray, list[int], list[tuple[Effect, slice]]] | None = None
        self._reused_holds = b""  # the nonlinear parameters the reused design's moving columns hold
        self.reuse_design = reuse_design
        self._kept: dict[str, tuple[bytes, np.ndarray]] = {}  # effect -> (its nonlinear parameters, its columns)
        self._weighted: tuple[list[np.ndarray], inertial.DesignRows] | None = None

    def split_nonlinear(self, x: np.ndarray) -> dict[str, np.ndarray]:
        out, start = {}, 0
        for effect, size in zip(self.effects, self.nl_sizes, strict=True):
            out[effect.name] = np.asarray(x[start : start + size], dtype=float)
            start += size
        return out

    def delay(self, nonlinear: dict[str, np.ndarray]) -> float:
        """Time shift of the prediction (:meth:`Effect.prediction_shift`): the command leads what it causes by an
        actuation delay; a sensor's reading lags the torque by its own."""
        moves = [effect.prediction_shift(float(nonlinear[effect.name][0]), self.signals.forward)
                 for effect in self.effects if effect.time_shift and not effect.lowpass]
        return float(sum(moves)) if moves else 0.0

    def lag(self, nonlinear: dict[str, np.ndarray]) -> float:
        """First-order lag of the prediction (:meth:`Effect.prediction_lag`; a sum of time constants: at the
        frequencies of a motion two low-passes in a row lag by the sum of theirs)."""
        lags = [effect.prediction_lag(float(nonlinear[effect.name][0]), self.signals.forward)
                for effect in self.effects if effect.time_shift and effect.lowpass]
        return float(sum(lags)) if lags else 0.0

    def retimed(self, nonlinear: dict[str, np.ndarray]) -> bool:
        """Whether the prediction is moved in time at all (a delay or a first-order lag)."""
        return self.delay(nonlinear) != 0.0 or self.lag(nonlinear) != 0.0

    def retime(self, values: np.ndarray, nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """``values`` (samples first) as the model's lags move the prediction (:func:`effects.timing.retime`)."""
        return retime(values, self.signals.time, self.signals.segments, self.delay(nonlinear), self.lag(nonlinear))

    def held_rows(self, effect: Effect) -> np.ndarray:
        """The joints' rows where ``effect``'s columns are zero: a drive effect's on the still joints, and a line kept
        on some joints on the others."""
        rows = set(self.still_rows.tolist()) if effect.drive else set()
        if effect.name in self.effect_joints:
            kept = set(self.effect_joints[effect.name])
            rows |= {k for k, joint in enumerate(self.signals.joint_names) if joint not in kept}
        return np.array(sorted(rows), dtype=int)

    def without_still(self, effect: Effect, cols: np.ndarray) -> np.ndarray:
        """An effect's columns (N, n, k) with its :meth:`held_rows` zero: its own parameters there, which act on
        their joint alone, are then not fitted (the solve leaves a column it cannot see at zero, the nominal value);
        every other effect's columns as they are."""
        rows = self.held_rows(effect)
        if not rows.size:
            return cols
        cols = cols.copy()
        cols[:, rows, :] = 0.0
        return cols

    def block(self, effect: Effect, nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """One effect's columns (N, n, k) at the given nonlinear parameters (before the time shift)."""
        cols = self.static_columns.get(effect.name)
        if cols is None:
            key = np.asarray(nonlinear[effect.name], dtype=float).tobytes()
            kept = self._kept.get(effect.name)
            if kept is not None and kept[0] == key:
                cols = kept[1]
            else:
                cols = self.without_still(effect, self.per_run_removed(
                    effect.columns(self.signals, self.states[effect.name], nonlinear[effect.name])[0]))
                if cols.nbytes <= KEPT_BLOCK_BYTES and not self.reuse_design:  # the refinement's move every step
                    self._kept[effect.name] = (key, cols)
        if self.signals.forward and effect.drive:
            cols = -cols  # forward, the drive's terms are taken from the command before the link-side sensor
        return cols

    def held_in_time(self, effect: Effect) -> bool:
        """Whether the lags leave ``effect``'s columns where they are: a drive's on the drive side (:meth:`shift`)."""
        return bool(self.signals.forward and effect.drive)

    def shift(self, columns: np.ndarray, effects: Sequence[Effect], sizes: Sequence[int],
              nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """Columns as they enter the prediction: moved by the lags (:meth:`retime`), except a drive's on the
        drive side (the command is delayed; the rotor inertia and friction act on the motion as it is). Only the
        columns that move are retimed: on the drive side most are a drive's (each column is retimed on its own,
        so the bits are those of retiming them all)."""
        if not self.retimed(nonlinear) or not self.signals.forward:
            return self.retime(columns, nonlinear)
        held = np.concatenate([np.full(size, self.held_in_time(effect)) for effect, size in zip(effects, sizes, strict=True)]
                              or [np.zeros(0, dtype=bool)])
        if not held.any():
            return self.retime(columns, nonlinear)
        if held.all():  # as without a lag: the columns themselves
            return columns
        shifted = columns.copy()
        shifted[:, :, ~held] = self.retime(columns[:, :, ~held], nonlinear)
        return shifted

    def shifted_design(self, nonlinear: dict[str, np.ndarray]) -> tuple[np.ndarray, list[int]]:
        design, sizes = self.design(nonlinear)
        return self.shift(design, self.effects, sizes, nonlinear), sizes

    def base(self, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """The prediction without the linear columns: nominal and offsets, moved by the lags; plus the unshifted term."""
        out = self.retime(self.signals.tau_nominal + self.offsets(theta), nonlinear)
        out = out if self.signals.unshifted is None else out + self.signals.unshifted
        if self.run_bases is not None:  # plus each run's drift, estimated on the run: what the rest leaves of it
            assert self.signals.tau is not None
            out = self.signals.tau - remove_runs(self.signals.tau - out, self.run_bases, self.drift_rows)
        return out

    def per_run_removed(self, columns: np.ndarray) -> np.ndarray:
        """``columns`` less what each run's own drift takes of them (:attr:`run_bases`; as they are without one)."""
        if self.run_bases is None or not columns.size:
            return columns
        return remove_runs(columns, self.run_bases, self.drift_rows)

    def design(self, nonlinear: dict[str, np.ndarray]) -> tuple[np.ndarray, list[int]]:
        """Columns (N, n, p) at the given nonlinear parameters (before the time shift) and sizes."""
        if self._reused is not None:
            design, sizes, moving = self._reused
            holds = self._moving_key(nonlinear, moving)
            if holds != self._reused_holds:  # the refinement's Jacobian asks for the design its residual just made
                for effect, columns in moving:
                    design[:, :, columns] = self.block(effect, nonlinear)
                self._reused_holds = holds
            return design, list(sizes)
        blocks, sizes = self._blocks(nonlinear)
        n_samples, n = self.signals.q.shape
        design = np.concatenate(blocks, axis=2) if blocks else np.zeros((n_samples, n, 0))
        if self.reuse_design:
            bounds = np.cumsum([0, *sizes])
            moving = [(effect, slice(int(bounds[k]), int(bounds[k + 1]))) for k, effect in enumerate(self.effects)
                      if sizes[k] and effect.name not in self.static_columns]
            self._reused = (design, list(sizes), moving)
            self._reused_holds = self._moving_key(nonlinear, moving)
        return design, sizes

    @staticmethod
    def _moving_key(nonlinear: dict[str, np.ndarray], moving: Sequence[tuple[Effect, slice]]) -> bytes:
        """The nonlinear parameters a reused design's moving columns were computed at (they depend on nothing else)."""
        return b"|".join(np.asarray(nonlinear[effect.name], dtype=float).tobytes() for effect, _ in moving)

    def columns_of(self, effect: Effect, design: np.ndarray, sizes: Sequence[int]) -> np.ndarray:
        """``effect``'s columns in ``design`` (a :meth:`design` or :meth:`shifted_design`, laid out by ``sizes``)."""
        k = self.effects.index(effect)
        start = int(sum(sizes[:k]))
        return design[:, :, start : start + sizes[k]]

    def weighted_rows(self, blocks: list[np.ndarray]) -> inertial.DesignRows:
        """The weighted design of these columns as rows (:class:`sim2real.identification.inertial.DesignRows`); the last one is
        kept when it fits in one chunk (the consistent fit and the bootstrap put the same one together)."""
        if self._weighted is not None and len(self._weighted[0]) == len(blocks) and all(
                a is b for a, b in zip(self._weighted[0], blocks, strict=True)):
            return self._weighted[1]
        rows = inertial.DesignRows(blocks, self.weights)
        self._weighted = (list(blocks), rows) if rows.shape[0] <= blas.CHUNK_ROWS else None
        return rows

    def _blocks(self, nonlinear: dict[str, np.ndarray]) -> tuple[list[np.ndarray], list[int]]:
        """Each effect's columns (before the time shift; a time shift has none) and their sizes."""
        blocks, sizes = [], []
        for effect in self.effects:
            if effect.time_shift or effect.per_run:  # a lag of the prediction, or a drift projected out: no columns
                sizes.append(0)
                continue
            cols = self.block(effect, nonlinear)
            blocks.append(cols)
            sizes.append(cols.shape[2])
        return blocks, sizes

    def offsets(self, theta: dict[str, np.ndarray]) -> np.ndarray:
        total = np.zeros_like(self.signals.tau_nominal)
        for effect in self.effects:
            if effect.name in theta:
                term = effect.offset(self.signals, self.states[effect.name], theta[effect.name])
                if term is not None:
                    total = total + term
        return total

    def predict(self, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray],
                shifted: tuple[np.ndarray, list[int]] | None = None, base: np.ndarray | None = None) -> np.ndarray:
        """The prediction; ``shifted``: :meth:`shifted_design` at ``nonlinear`` when the caller has it already;
        ``base``: :meth:`base` at ``theta`` and ``nonlinear``, likewise.

        Without a time shift the design is put together a few thousand samples at a time, never whole (on a
        long log the largest array of a fit): the same bits, as matmul multiplies sample by sample."""
        if shifted is None and not self.retimed(nonlinear):
            return self.predict_from_blocks(theta, nonlinear, *self._blocks(nonlinear), base=base)
        design, sizes = self.shifted_design(nonlinear) if shifted is None else shifted
        base = self.base(theta, nonlinear) if base is None else base
        if design.shape[2] == 0:  # a delay alone: what the product of no columns adds, without forming it
            return base + 0.0
        return base + design @ _flatten_theta(self.effects, theta, sizes)

    def predict_from_blocks(self, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray],
                            blocks: list[np.ndarray], sizes: list[int], base: np.ndarray | None = None) -> np.ndarray:
        """:meth:`predict` without a time shift from the effects' columns (:meth:`_blocks`), the design put
        together a few thousand samples at a time."""
        flat = _flatten_theta(self.effects, theta, sizes)
        base = self.base(theta, nonlinear) if base is None else base
        n_samples, n = self.signals.q.shape
        out = np.empty(base.shape, dtype=np.result_type(base, flat))
        step = max(1, PREDICT_CHUNK_BYTES // max(1, 8 * n * int(flat.size)))
        for start in range(0, n_samples, step):
            rows = slice(start, start + step)
            design = (np.concatenate([b[rows] for b in blocks], axis=2) if blocks
                      else np.zeros((len(base[rows]), n, 0)))
            out[rows] = base[rows] + design @ flat
        return out


def _flatten_theta(effects: list[Effect], theta: dict[str, np.ndarray], sizes: list[int]) -> np.ndarray:
    parts = [theta.get(e.name, np.zeros(s))[:s] for e, s in zip(effects, sizes, strict=True) if s]
    return np.concatenate(parts) if parts else np.zeros(0)


def _split_theta(effects: list[Effect], flat: np.ndarray, sizes: list[int]) -> dict[str, np.ndarray]:
    out, start = {}, 0
    for effect, size in zip(effects, sizes, strict=True):
        out[effect.name] = flat[start : start + size]
        start += size
    return out


def subset_signals(signals: Signals, rows: np.ndarray) -> Signals:
    """The ``rows`` (sorted) of ``signals``, as :meth:`sim2real.identification.fitting.TorqueData.subset` takes them of the data:
    what :func:`sim2real.identification.fitting.make_signals` computes on the subset, without computing it again."""
    segments = kept_segments(signals.segments, rows)
    regressor = signals._regressor[rows] if signals._regressor is not None else None
    parent = signals
    return Signals(
        joint_names=signals.joint_names, time=signals.time[rows], q=signals.q[rows], qd=signals.qd[rows],
        qdd=signals.qdd[rows], tau_nominal=signals.tau_nominal[rows], segments=segments,
        tau=None if signals.tau is None else signals.tau[rows],
        regressor_fn=lambda: parent.regressor[rows], nominal=signals.nominal, forward=signals.forward,
        unshifted=None if signals.unshifted is None else signals.unshifted[rows], _regressor=regressor,
        gravity_fn=None if signals.gravity_fn is None else lambda: parent.unit_gravity[rows],
        _gravity=None if signals._gravity is None else signals._gravity[rows],
    )


def _values(effects: list[Effect], theta, nonlinear, signals: Signals, states) -> dict[str, Any]:
    """Structured values (:meth:`Effect.values`) of the linear parameters ``theta``."""
    theta = _applied(effects, theta, signals)
    return {e.name: e.values(theta[e.name], nonlinear[e.name], signals, states[e.name]) for e in effects}


def _applied(effects: list[Effect], theta: Mapping[str, np.ndarray], signals: Signals) -> dict[str, np.ndarray]:
    """``theta`` as the values give it: with a gain (judged / applied torque), joint-local effects rescaled to
    applied torque, except a sensor's own bias, which is added after its gain. Each array may be stacked over
    bootstrap replicates (replicates, size): the same numbers, row by row."""
    theta = dict(theta)
    scaling = next((e for e in effects if e.scales_judged and np.shape(theta.get(e.name, ()))[-1]), None)
    if scaling is not None and not signals.forward:  # forward, every term is already applied torque
        gain = 1.0 + theta[scaling.name]
        divisor = np.where(np.abs(gain) > 1e-6, gain, 1.0)
        joints = np.shape(gain)[-1]
        for effect in effects:
            if (effect.joint_local and not effect.scales_judged and effect.name != "torque_bias"
                    and np.shape(theta[effect.name])[-1]):
                # an effect with several coefficients per joint (a ripple's sine and cosine) holds them joint by joint
                shape = np.shape(theta[effect.name])
                per_joint = np.reshape(theta[effect.name], (*shape[:-1], shape[-1] // joints, joints))
                theta[effect.name] = np.reshape(per_joint / divisor[..., None, :], shape)
    return theta

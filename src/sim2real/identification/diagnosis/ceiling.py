"""The model-free ceiling: how much of the last rung's residual any function of the motion explains.

When no effect of the library is decisive, the user needs to know what kind of thing is left. A flexible
learner (scikit-learn's ``HistGradientBoostingRegressor``, one per joint) is fitted on the motion (q, qd,
qdd of every joint), and another on the joint's dynamics (the torque the rung predicts for it, the sign and
magnitude of its velocity, its gravity torque), to the last rung's residual on the fit runs and judged on the
holdout runs, like every rung. Per joint, above its floor:

* **ceiling well below the rung** (the learner's holdout RMSE under :data:`CLOSE_TO_RUNG` x the rung's):
  something that is a function of the motion is missing from the library. Which motion it follows is
  read off the learner (permutation importance on the holdout runs), so the user knows what to model.
* **ceiling close to the rung**: nothing of the motion explains the rest. What it does follow is tested,
  each as the share of the joint's excess above its floor it removes (every run, fit and holdout):
  ``time`` (a smooth function of time within each run: a warm-up, a drifting sensor offset), ``run``
  (one offset per run) and ``history`` (the displacement since the last velocity reversal and the direction
  of motion, fitted on the fit runs and judged on the holdout: hysteresis, presliding friction).

The learner runs on one OpenMP thread with a fixed seed: the same numbers on every machine's core count.
This module fits the learners and reads them; the features they read are built in
:mod:`~sim2real.identification.diagnosis.ceiling_features`.
"""

from __future__ import annotations

import importlib
from dataclasses import replace
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.diagnosis.ceiling_features import (
    DYNAMICS_LEARNER, DYNAMICS_TREES, POSE_LEARNERS, LearnerFeatures, _chosen_features, dynamics_features, feature,
    motion_features, period_harmonics, pose_features, position_harmonics, signed_products, since_reversal,
)
from sim2real.identification.diagnosis.ceiling_records import CeilingReading, EffectAdvice, ModelFreeCeiling
from sim2real.identification.effects.position_ripple import best_periods

# The learner's holdout RMSE at or above this fraction of the rung's: what is left is not a function of the
# motion ("within about 15 %"); below it, the library lacks an effect the motion explains.
CLOSE_TO_RUNG = 0.85
# A test of what the rest follows names it when it removes at least this share of the joint's excess.
MIN_SHARE = 0.3
# What drifts within a run: a smooth function of time removes at least this share of the excess more than one
# offset per run does (else the runs merely sit at different offsets).
DRIFT_BEYOND_OFFSET = 0.1
TIME_DEGREE = 3  # a cubic in time within each run: a warm-up, a slow drift; not the motion's faster periods
LEARNER = ("per joint, the best on the holdout runs of five learners fitted on the fit runs' residual of the last "
           "rung: HistGradientBoostingRegressor on q, qd, qdd of every joint and on the joint's dynamics (the torque "
           "the rung predicts for it, the sign and magnitude of its velocity, its gravity torque), a ridge regression "
           "on the predicted torque times the sign of the velocity (a friction growing with the load, which trees cannot "
           "carry from one run's torques to another's), and two ridge regressions on harmonics of the joint's own position (a ripple the trees cannot "
           "carry from one run's positions to another's): of whole turns, and of the period one sinusoid of the "
           "position fits best (a ripple of any period), and two ridge regressions on the pose, which carry a function of "
           "it to poses the fit runs never visited: on the joint's gravity torque under unit gravity along the base's x, "
           "y and z, and on those with the sine and cosine of every joint's angle")
# The pose learners' regularisation is chosen on contiguous blocks of the fit runs: a pose the next block
# visits is not one the learner saw (leave-one-sample-out would choose by neighbours and extrapolate noise).
POSE_BLOCKS = 5
# The pose's features that a gravity turned sideways follows: where they carry a pose learner's gain, the effect
# of the library that models it is named.
SIDEWAYS = ("gravity_along_x", "gravity_along_y")
MOUNT_EFFECT = "base_mount"
# What sits at an offset of its own in each run or drifts within one is the sensor's, not the robot's; yet every fit
# takes part of it for the robot (a link inertia fitted to one run's offset misses the next run's, and a candidate
# the library has can then fail its trial): said where the ceiling finds it, with what a user does about it.
OFFSET_KINDS = ("time", "run")
# ... and for runs already logged, the effect that estimates each run's drift on the run itself (never a candidate:
# no held-out run can judge it).
DRIFT_EFFECT = "sensor_drift"


def _learner(seed: int = 0) -> Any:
    from sklearn.ensemble import HistGradientBoostingRegressor

    # Moderate trees, no early stopping (a random validation split of time-correlated samples would reward
    # fitting the noise); judged on runs it never saw, so overfitting only makes the ceiling conservative.
    return HistGradientBoostingRegressor(max_iter=100, learning_rate=0.15, max_leaf_nodes=15, min_samples_leaf=40,
                                         l2_regularization=1.0, early_stopping=False, random_state=seed)


# The learner trains on at most this many samples, evenly spaced (a 10-minute log at the fit's 200 Hz is 120 000):
# its ceiling is a statement about the shape of what is left, which a few minutes of motion show.
MAX_TRAIN_ROWS = 20_000


def _train_rows(n: int) -> slice:
    return slice(None, None, max(1, -(-n // MAX_TRAIN_ROWS)))


def _harmonic_learner() -> Any:
    from sklearn.linear_model import RidgeCV

    return RidgeCV(alphas=np.logspace(-3, 3, 13))


def _pose_learner() -> Any:
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from sim2real.identification.diagnosis.blocked_ridge import BlockedRidgeCV

    return make_pipeline(StandardScaler(), BlockedRidgeCV(alphas=np.logspace(-3, 3, 13), blocks=POSE_BLOCKS))


def _dynamics_learner() -> Any:
    from sklearn.linear_model import RidgeCV
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    # Standardised: a torque of tens of N*m and a sign of one are penalised alike.
    return make_pipeline(StandardScaler(), RidgeCV(alphas=np.logspace(-3, 3, 13)))


def _excess_share(before: np.ndarray, after: np.ndarray, floor: float) -> float:
    """Share of ``before``'s energy above white noise at ``floor`` that ``after`` no longer has (0..1)."""
    sse_before, sse_after = float(np.sum(before**2)), float(np.sum(after**2))
    excess = sse_before - before.size * floor**2
    return float(np.clip((sse_before - sse_after) / excess, 0.0, 1.0)) if excess > 0 else 0.0


def _per_run_fit(residual: np.ndarray, time: np.ndarray, segments: Sequence[slice], degree: int) -> np.ndarray:
    """``residual`` less its least-squares polynomial of ``degree`` in time within each run (0: the run's mean)."""
    out = np.array(residual, dtype=float)
    for seg in segments:
        t = time[seg]
        span = max(float(t[-1] - t[0]), 1e-12)
        basis = np.polynomial.legendre.legvander(2.0 * (t - t[0]) / span - 1.0, degree)
        coefficients, *_ = np.linalg.lstsq(basis, out[seg], rcond=None)
        out[seg] -= basis @ coefficients
    return out


def _stacked(first: Any, second: Any, name: str) -> np.ndarray:
    return np.concatenate([getattr(first, name), getattr(second, name)])


def _drift_shares(j: int, fit_data: Any, fit_residual: np.ndarray, holdout_data: Any, holdout_residual: np.ndarray,
                  floor: float) -> dict[str, float]:
    """Shares of joint ``j``'s excess (every run, fit and holdout) that a smooth function of time within each run
    and one offset per run remove."""
    residual = np.concatenate([fit_residual[:, j], holdout_residual[:, j]])
    time = _stacked(fit_data, holdout_data, "time")
    offset = fit_data.n_samples
    segments = [*fit_data.segments, *(slice(s.start + offset, s.stop + offset) for s in holdout_data.segments)]
    return {
        "time": _excess_share(residual, _per_run_fit(residual, time, segments, TIME_DEGREE), floor),
        "run": _excess_share(residual, _per_run_fit(residual, time, segments, 0), floor),
    }


def _beyond_motion(j: int, fit_data: Any, fit_residual: np.ndarray, holdout_data: Any, holdout_residual: np.ndarray,
                   floor: float) -> dict[str, float]:
    """Shares of joint ``j``'s excess that time within a run, the run and the history since a reversal explain."""
    shares = _drift_shares(j, fit_data, fit_residual, holdout_data, holdout_residual, floor)

    def history(data: Any) -> np.ndarray:
        return np.column_stack([since_reversal(data.q, data.qd, data.segments)[:, j], data.qd[:, j]])

    rows = _train_rows(fit_data.n_samples)
    learner = _learner().fit(history(fit_data)[rows], fit_residual[rows, j])
    after = holdout_residual[:, j] - learner.predict(history(holdout_data))
    shares["history"] = _excess_share(holdout_residual[:, j], after, floor)
    return {k: round(v, 4) for k, v in shares.items()}


def _named(shares: dict[str, float]) -> str | None:
    """What the rest of a joint follows, from :func:`_beyond_motion`'s shares (None: none of them)."""
    if shares["history"] >= MIN_SHARE and shares["history"] > shares["time"]:
        return "history"
    if shares["time"] >= MIN_SHARE and shares["time"] - shares["run"] >= DRIFT_BEYOND_OFFSET:
        return "time"
    if shares["run"] >= MIN_SHARE:
        return "run"
    return None


def _gains_most(learner: Any, features: np.ndarray, target: np.ndarray,
                names: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The motion the learner's gain follows: the features whose permutation on the holdout costs it most (the
    rise of its squared error when that feature's column is shuffled, one seeded shuffle each)."""
    base = float(np.mean((target - learner.predict(features)) ** 2))
    rng = np.random.default_rng(0)
    importance = np.zeros(features.shape[1])
    for k in range(features.shape[1]):
        shuffled = features.copy()
        shuffled[:, k] = rng.permutation(shuffled[:, k])
        importance[k] = float(np.mean((target - learner.predict(shuffled)) ** 2)) - base
    order = np.argsort(-importance, kind="stable")
    top = float(importance[order[0]])
    return [names[i] for i in order[:3] if top > 0 and importance[i] >= 0.5 * top]


# Regimes of the joint's own motion where a learner's gain can concentrate (sim2real.report.regimes defines the same two
# for the gap report; these need no model): slow motion and reversals, hard accelerations.
GAIN_REGIMES = {
    "slow_reversal": lambda qd, qdd: np.abs(qd) < 0.15 * np.percentile(np.abs(qd), 99),
    "hard_acceleration": lambda qd, qdd: np.abs(qdd) > np.percentile(np.abs(qdd), 80),
}
CONCENTRATED = 1.5  # a regime holds the gain when its gain per sample is this many times the joint's average


def _gain_regime(before: np.ndarray, after: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> str | None:
    """The regime of the joint's motion where the learner's gain (fall of the squared residual) concentrates."""
    gain = before**2 - after**2
    average = float(np.mean(gain))
    if average <= 0:
        return None
    best, density = None, CONCENTRATED * average
    for name, inside in GAIN_REGIMES.items():
        mask = inside(qd, qdd)
        if 20 <= int(mask.sum()) < mask.size and float(np.mean(gain[mask])) >= density:
            best, density = name, float(np.mean(gain[mask]))
    return best


def _at_floor(rung: float, floor: float, noise_floor_factor: float) -> bool:
    return floor > 0 and rung <= noise_floor_factor * floor


def _learners(j: int, fit_data: Any, fit_column: np.ndarray, holdout_data: Any, holdout_column: np.ndarray,
              features: LearnerFeatures | None = None) -> tuple[str, np.ndarray, Any, float]:
    """The best on the holdout of the learners of :data:`LEARNER`, fitted on joint ``j``'s residual
    ``fit_column``: (its name, ``holdout_column`` less its prediction, the trees of the chosen kind, the searched
    period). A tie goes to the earlier (the trees on the motion, on the dynamics, the signed torques, the pose, then whole
    turns); ``features``: what the learners beside the trees on the motion read (:class:`LearnerFeatures`). Called on
    one OpenMP thread."""
    dynamics, pose = (features.dynamics, features.pose) if features is not None else (None, None)
    x_fit, _ = motion_features(fit_data)
    x_holdout, _ = motion_features(holdout_data)
    train = _train_rows(fit_data.n_samples)
    learner = _learner().fit(x_fit[train], fit_column[train])
    trees = holdout_column - learner.predict(x_holdout)
    tried = [("trees on the motion", trees)]
    kept = {"trees on the motion": learner}
    if dynamics is not None:
        kept[DYNAMICS_TREES] = _learner().fit(dynamics[0][train, j], fit_column[train])
        tried.append((DYNAMICS_TREES, holdout_column - kept[DYNAMICS_TREES].predict(dynamics[1][:, j])))
        kept[DYNAMICS_LEARNER] = _dynamics_learner().fit(signed_products(dynamics[0][train, j]), fit_column[train])
        tried.append((DYNAMICS_LEARNER,
                      holdout_column - kept[DYNAMICS_LEARNER].predict(signed_products(dynamics[1][:, j]))))
    for name in POSE_LEARNERS if pose is not None else ():
        assert pose is not None
        kept[name] = _pose_learner().fit(pose_features(fit_data.q, pose[0], j, name)[train], fit_column[train])
        tried.append((name, holdout_column - kept[name].predict(pose_features(holdout_data.q, pose[1], j, name))))
    ripple = _harmonic_learner().fit(position_harmonics(fit_data.q[train, j]), fit_column[train])
    harmonics = holdout_column - ripple.predict(position_harmonics(holdout_data.q[:, j]))
    period = float(best_periods(fit_data.q[train, j:j + 1], fit_column[train, None])[0][0])
    searched = _harmonic_learner().fit(period_harmonics(fit_data.q[train, j], period), fit_column[train])
    of_period = holdout_column - searched.predict(period_harmonics(holdout_data.q[:, j], period))
    chosen, after = min([*tried, ("position harmonics", harmonics), ("a ripple of the searched period", of_period)],
                        key=lambda item: float(np.mean(item[1] ** 2)))
    return chosen, after, kept.get(chosen, learner), period


def _motion_beyond_drift(j: int, drift: str, residuals: tuple[Any, np.ndarray, Any, np.ndarray], floor: float,
                         noise_floor_factor: float, features: LearnerFeatures | None = None) -> bool:
    """Whether the learners still explain joint ``j``'s residual once each run's own ``drift`` (its offset, or its
    smooth function of time) is taken out of every run: a function of the motion beside the drift, not its
    imitation. ``residuals``: the fit data, the rung's residual on it, the holdout data and the rung's residual on
    it."""
    fit_data, fit_residual, holdout_data, holdout_residual = residuals
    degree = TIME_DEGREE if drift == "time" else 0
    fit_column = _per_run_fit(fit_residual[:, j], fit_data.time, fit_data.segments, degree)
    holdout_column = _per_run_fit(holdout_residual[:, j], holdout_data.time, holdout_data.segments, degree)
    rung = float(np.sqrt(np.mean(holdout_column**2)))
    if _at_floor(rung, floor, noise_floor_factor):
        return False
    _, after, _, _ = _learners(j, fit_data, fit_column, holdout_data, holdout_column, features)
    return float(np.sqrt(np.mean(after**2))) < CLOSE_TO_RUNG * rung


def _joint_ceiling(j: int, *, fit_data: Any, fit_residual: np.ndarray, holdout_data: Any,
                   holdout_residual: np.ndarray, noise_floor_factor: float, floors: Sequence[float],
                   features: LearnerFeatures | None = None) -> tuple[CeilingReading, np.ndarray]:
    """Joint ``j``'s row of :func:`model_free_ceiling` and its holdout residual after the better learner (the
    rung's own where the joint is at its floor); ``floors``: each joint's as the ladder judges by it; ``features``:
    what the learners beside the trees on the motion read."""
    from threadpoolctl import threadpool_limits

    floor = float(floors[j])
    rung = float(np.sqrt(np.mean(holdout_residual[:, j] ** 2)))
    if _at_floor(rung, floor, noise_floor_factor):
        # nothing above the floor for a learner to explain: the ceiling is the rung itself
        return (CeilingReading(rung_rmse=round(rung, 6), ceiling_rmse=round(rung, 6), rung_x_floor=round(rung / floor, 3),
                               ceiling_x_floor=round(rung / floor, 3), ratio=1.0, explained_beyond_noise=0.0,
                               kind="at_floor", fitted=False), np.array(holdout_residual[:, j], dtype=float))
    with threadpool_limits(limits=1, user_api="openmp"):
        chosen, after, learner, period = _learners(j, fit_data, fit_residual[:, j], holdout_data,
                                                   holdout_residual[:, j], features)
        periodic = chosen not in ("trees on the motion", DYNAMICS_TREES, DYNAMICS_LEARNER, *POSE_LEARNERS)
        ceiling = float(np.sqrt(np.mean(after**2)))
        row = CeilingReading(
            rung_rmse=round(rung, 6), ceiling_rmse=round(ceiling, 6), rung_x_floor=round(rung / floor, 3),
            ceiling_x_floor=round(ceiling / floor, 3), ratio=round(ceiling / rung, 4) if rung > 0 else 1.0,
            explained_beyond_noise=round(_excess_share(holdout_residual[:, j], after, floor), 4),
            kind="not_motion", fitted=True, learner=chosen)
        if ceiling < CLOSE_TO_RUNG * rung:
            ripple = {"period": period} if chosen == "a ripple of the searched period" else {}
            x_holdout, names = _chosen_features(chosen, j, holdout_data, features)
            gains = ([feature("periodic_position", holdout_data.joint_names[j], **ripple)] if periodic
                     else _gains_most(learner, x_holdout, holdout_residual[:, j], names))
            row = replace(
                row, kind="motion", gains_most_with=tuple(gains),
                # a gravity turned sideways: the library's mount carries it
                effect=MOUNT_EFFECT if chosen in POSE_LEARNERS and any(f["feature"] in SIDEWAYS for f in gains) else None,
                gains_most_in=_gain_regime(holdout_residual[:, j], after, holdout_data.qd[:, j], holdout_data.qdd[:, j]))
            # Where each run's motion follows its time (one excitation, run after run), a function of the motion can
            # imitate a warm-up or an offset per run. Where one of those removes as much, it is named; the learners
            # fitted again without it say whether the motion explains anything beside it.
            shares = _drift_shares(j, fit_data, fit_residual, holdout_data, holdout_residual, floor)
            drift = _named({**shares, "history": 0.0})
            if drift is not None and shares[drift] >= row.explained_beyond_noise:
                row = replace(row, beyond_motion={k: round(v, 4) for k, v in shares.items()}, follows=drift,
                              imitated=not _motion_beyond_drift(
                                  j, drift, (fit_data, fit_residual, holdout_data, holdout_residual), floor,
                                  noise_floor_factor, features))
        else:
            shares = _beyond_motion(j, fit_data, fit_residual, holdout_data, holdout_residual, floor)
            row = replace(row, beyond_motion=shares, follows=_named(shares))
    return row, after


def model_free_ceiling(fit_data: Any, fit_residual: np.ndarray, holdout_data: Any, holdout_residual: np.ndarray,
                       noise_floor_factor: float = 1.5, workers: int = 1, model_effects: Sequence[str] = (),
                       nominal_dynamics: Any = None) -> ModelFreeCeiling:
    """The ceiling of ``diagnosis.model_free`` in gap.json (see the module docstring).

    ``fit_data``/``holdout_data``: :class:`sim2real.identification.fitting.TorqueData`; the residuals are the last rung's
    (judged minus predicted torque) on them. Joints within ``noise_floor_factor`` of their floor are
    ``at_floor``: nothing to explain, no learner fitted (``fitted`` false; the ceiling is the rung's).
    ``workers``: processes the joints' learners are fitted on side by side (:func:`sim2real.forked.map_forked`:
    each joint's numbers are those it has alone). Where joints sit at an offset of each run's own or drift within
    it and ``model_effects`` lack :data:`DRIFT_EFFECT`, ``declare`` names it (the line of model.yaml the report
    advises for runs already logged). ``nominal_dynamics``: the nominal model
    (:class:`sim2real.assets.dynamics.RigidBodyModel`), whose gravity torque (N, n) is a feature of the dynamics
    learner and whose generalized gravity under unit gravity along x, y, z (N, n, 3) the pose learners' (None: they
    learn without, and there is no pose learner), computed only where a joint is learned. A joint whose pose learner's gain follows the gravity turned
    sideways names :data:`MOUNT_EFFECT` (``effect``); where the model lacks it, ``points_to`` lists those joints.
    """
    from sim2real.forked import map_forked
    from sim2real.identification.fitting.scoring import judged_floors

    joints = list(holdout_data.joint_names)
    floors = [float(f) for f in judged_floors(holdout_data.noise_floor)]
    learned = [j for j in range(len(joints)) if not _at_floor(
        float(np.sqrt(np.mean(holdout_residual[:, j] ** 2))), floors[j], noise_floor_factor)]
    if learned:  # the learners' modules imported once, before the fork; a model at its floor needs neither
        for module in ("sklearn.ensemble", "sklearn.linear_model"):
            importlib.import_module(module)
    model = nominal_dynamics
    features = LearnerFeatures(
        (dynamics_features(fit_data, fit_residual, model.gravity(fit_data.q) if model is not None else None),
         dynamics_features(holdout_data, holdout_residual, model.gravity(holdout_data.q) if model is not None else None)),
        (model.unit_gravity(fit_data.q), model.unit_gravity(holdout_data.q)) if model is not None else None,
    ) if learned else None
    rows = map_forked(_joint_ceiling, range(len(joints)), workers if learned else 1, {
        "fit_data": fit_data, "fit_residual": fit_residual, "holdout_data": holdout_data,
        "holdout_residual": holdout_residual, "noise_floor_factor": float(noise_floor_factor), "floors": floors,
        "features": features})
    per_joint = {joint: row for joint, (row, _) in zip(joints, rows, strict=True)}
    after = np.column_stack([column for _, column in rows])
    overall = float(np.sqrt(np.mean(after**2)))
    offsets = offset_joints(per_joint)
    mounted = [j for j, r in per_joint.items() if r.effect == MOUNT_EFFECT]
    return ModelFreeCeiling(
        learner=LEARNER, torque_rmse_overall=round(overall, 6),
        torque_rmse_per_joint={j: per_joint[j].ceiling_rmse for j in joints}, close_to_rung=CLOSE_TO_RUNG,
        per_joint=per_joint,
        declare=(EffectAdvice(DRIFT_EFFECT, tuple(offsets), f"- {DRIFT_EFFECT}")
                 if offsets and DRIFT_EFFECT not in model_effects else None),
        points_to=(EffectAdvice(MOUNT_EFFECT, tuple(mounted), f"- {MOUNT_EFFECT}")
                   if mounted and MOUNT_EFFECT not in model_effects else None))


def offset_joints(per_joint: Mapping[str, CeilingReading]) -> list[str]:
    """The joints where what is left sits at an offset of each run's own or drifts: no function of the motion, or
    one a drift removes as much of (:func:`imitated_joints`). Not a joint whose leftover follows a gravity turned
    sideways (``effect``): a held-out run judges the mount that carries it, no drift estimated on every run stands in
    for it."""
    return [j for j, r in per_joint.items() if r.kind != "at_floor" and r.follows in OFFSET_KINDS and not r.effect]


def imitated_joints(per_joint: Mapping[str, CeilingReading]) -> list[str]:
    """The joints where a learner on the motion explains much of what is left, yet an offset or drift of each run's
    own removes at least as much, and without it the learner explains nothing more: the motion merely follows the
    run's time."""
    return [j for j, r in per_joint.items() if r.kind == "motion" and r.imitated]

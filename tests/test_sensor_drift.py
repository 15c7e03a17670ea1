"""A torque sensor's drift within each run (effects/sensor_drift.py): estimated on every run itself, the holdout runs
included, by projecting each run's drift shapes (polynomials and settling exponentials in its time) out of the judged
torque and of every column.

What it promises, each on real inputs: the projection removes exactly each run's drift shapes; a model
with it predicts the same residual whatever drift each run adds (fit and holdout alike), and fits the same robot;
it is never a candidate, holds a torque bias, sits in the model of every link, and writes nothing into the assets.
The loop on the lab's ``drift`` arm is tests/test_trustworthy_loop.py's.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import sysid_lab
from sim2real.excitation.config import identification_effects
from sim2real.identification import fitting, sides
from sim2real.identification.records import Side
from sim2real.report.verdicts import skip_reason
from sim2real.identification.diagnosis import candidates_to_try
from sim2real.identification.effects import EFFECTS, apply_to_spec, calibration_from_params
from sim2real.identification.effects.sensor_drift import DEGREE, SETTLING, remove_runs, run_bases


def run_segments(lengths: list[int]) -> list[slice]:
    bounds = np.cumsum([0, *lengths])
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def drift_of_each_run(time: np.ndarray, segments: list[slice], joints: int, seed: int) -> np.ndarray:
    """A polynomial of DEGREE in each run's own time and its settling exponentials (a warm-up), other coefficients in
    every run and joint (N, joints)."""
    rng = np.random.default_rng(seed)
    out = np.zeros((time.size, joints))
    for segment in segments:
        t = time[segment] - time[segment][0]
        span = max(float(t[-1]), 1e-9)
        shapes = np.vander(t / span, DEGREE + 1, increasing=True)
        if t.size > DEGREE + 1 + len(SETTLING):  # a run long enough for them: the basis holds them too
            shapes = np.column_stack([shapes, *(np.exp(-t / (fraction * span)) for fraction in SETTLING)])
        out[segment] = shapes @ rng.normal(scale=0.3, size=(shapes.shape[1], joints))
    return out


@settings(max_examples=30, deadline=None, derandomize=True)
@given(lengths=st.lists(st.integers(5, 300), min_size=1, max_size=4), joints=st.integers(1, 3),
       columns=st.integers(0, 3), seed=st.integers(0, 2**16))
def test_the_projection_removes_each_runs_drift_and_nothing_else(lengths, joints, columns, seed):
    """Any polynomial of DEGREE in each run's time and any settling of its exponentials (its own coefficients per run
    and joint) vanishes; what remains is orthogonal to every run's drift shapes, and projecting it again changes
    nothing (a projection)."""
    segments = run_segments(lengths)
    rng = np.random.default_rng(seed)
    time = np.sort(rng.uniform(0.0, 50.0, size=sum(lengths)))
    for segment in segments:  # each run's clock starts anew, at its own rate
        time[segment] = np.arange(segment.stop - segment.start) * rng.uniform(0.001, 0.05)
    bases = run_bases(time, segments)
    shape = (time.size, joints, columns) if columns else (time.size, joints)
    signal = rng.normal(size=shape)
    drift = drift_of_each_run(time, segments, joints * max(columns, 1), seed + 1).reshape(shape)
    removed = remove_runs(signal, bases)
    np.testing.assert_allclose(remove_runs(signal + drift, bases), removed, atol=1e-9)
    np.testing.assert_allclose(remove_runs(removed, bases), removed, atol=1e-9)
    for segment, basis in bases:
        block = removed[segment].reshape(segment.stop - segment.start, -1)
        np.testing.assert_allclose(basis.T @ block, 0.0, atol=1e-9)


@pytest.fixture(scope="module")
def runs(shared_lab):
    """The suite lab's real_arm_like runs (fit, holdout) and its nominal model."""
    fit_data, holdout_data = shared_lab.data("real_arm_like")
    return shared_lab.nominal, fit_data, holdout_data


def with_drift(data: fitting.TorqueData, seed: int) -> fitting.TorqueData:
    return dataclasses.replace(data, tau=data.tau + drift_of_each_run(data.time, data.segments, data.tau.shape[1], seed))


def test_a_model_with_it_fits_and_predicts_the_same_whatever_each_run_drifts(runs):
    """Adding any drift of each run's own to the judged torque of the fit runs leaves the fitted friction where it
    was, and adding another to the holdout leaves its residual where it was: each run's drift is estimated on that
    run itself. Without the line, the same drift moves both (the test can fail)."""
    nominal, fit_data, holdout_data = runs
    options = {"settings": sysid_lab.FAST_FIT, "uncertainty": False}
    model = ["viscous_friction", "sensor_drift"]
    clean = fitting.fit(model, nominal, fit_data, **options)
    drifted = fitting.fit(model, nominal, with_drift(fit_data, 3), **options)
    np.testing.assert_allclose(drifted.theta["viscous_friction"], clean.theta["viscous_friction"], rtol=1e-6,
                               atol=1e-9)
    residual = holdout_data.tau - fitting.predict(clean, nominal, holdout_data)
    moved = with_drift(holdout_data, 4)
    np.testing.assert_allclose(moved.tau - fitting.predict(clean, nominal, moved), residual, atol=1e-8)
    for segment, basis in run_bases(holdout_data.time, holdout_data.segments):  # no drift of its own is left
        np.testing.assert_allclose(basis.T @ residual[segment], 0.0, atol=1e-8)

    without = fitting.fit(["viscous_friction"], nominal, fit_data, **options)
    moved_fit = fitting.fit(["viscous_friction"], nominal, with_drift(fit_data, 3), **options)
    assert not np.allclose(moved_fit.theta["viscous_friction"], without.theta["viscous_friction"], rtol=1e-3)
    plain = holdout_data.tau - fitting.predict(without, nominal, holdout_data)
    assert not np.allclose(moved.tau - fitting.predict(without, nominal, moved), plain, atol=1e-3)


def test_a_line_kept_on_some_joints_estimates_their_drift_alone(runs):
    """``- sensor_drift: {joints: [...]}`` (the line the ceiling declares where the drift written for every joint
    would raise a joint): the kept joints' drift is estimated on each run, whatever it is; the other joints' readings
    are taken as they are, a drift added to them stays in their residual whole."""
    nominal, fit_data, holdout_data = runs
    kept = list(holdout_data.joint_names[::2])
    settings = {**sysid_lab.FAST_FIT, "effect_joints": {"sensor_drift": kept}}
    result = fitting.fit(["viscous_friction", "sensor_drift"], nominal, fit_data, settings=settings, uncertainty=False)
    assert result.effect_joints == {"sensor_drift": kept}
    residual = holdout_data.tau - fitting.predict(result, nominal, holdout_data)
    drift = drift_of_each_run(holdout_data.time, holdout_data.segments, holdout_data.tau.shape[1], 5)
    moved = dataclasses.replace(holdout_data, tau=holdout_data.tau + drift)
    after = moved.tau - fitting.predict(result, nominal, moved)
    on = [holdout_data.joint_names.index(j) for j in kept]
    off = [k for k in range(len(holdout_data.joint_names)) if k not in on]
    np.testing.assert_allclose(after[:, on], residual[:, on], atol=1e-8)
    np.testing.assert_allclose(after[:, off], residual[:, off] + drift[:, off], atol=1e-8)
    assert EFFECTS["sensor_drift"].per_joint_line


def test_it_is_declared_never_proposed_and_holds_a_torque_bias():
    """No held-out run can judge an effect estimated on every run itself: the diagnosis skips it, saying why; in a
    model, it holds a constant offset (torque_bias is a special case of it) and sits in every link's model."""
    tried, skipped = candidates_to_try(["link_inertia"], "tau", False)
    assert "sensor_drift" not in tried and "torque_bias" in tried
    reason = {s.effect: skip_reason(s) for s in skipped}["sensor_drift"]
    assert reason.startswith("estimated on every run itself, the holdout runs included")
    tried, skipped = candidates_to_try(["link_inertia", "sensor_drift"], "tau", False)
    assert "torque_bias" not in tried
    assert {s.effect: skip_reason(s) for s in skipped}["torque_bias"].startswith("sensor_drift in the model already")
    model = ["link_inertia", "sensor_drift", "actuation_delay"]
    assert sides.effects_of_side(model, Side.BODY) == ["link_inertia", "sensor_drift"]
    assert sides.effects_of_side(model, Side.DRIVE) == ["sensor_drift", "actuation_delay"]
    told = [name for fact in sides.separability("separate", model, [])["can_tell"] for name in fact["effects"]]
    assert "link_inertia" in told and "sensor_drift" not in told, "told apart from nothing: it is never judged"


def test_the_assets_and_the_design_leave_the_drift_out():
    """A sensor's drift is no property of the robot: the calibrated MJCF and the calibration get nothing, and the
    excitation design does not aim at it."""
    import mujoco

    spec = mujoco.MjSpec.from_string("<mujoco><worldbody><body><joint name='j' damping='0.1'/>"
                                     "<geom size='0.1'/></body></worldbody></mujoco>")
    before = spec.to_xml()
    params = {"effects": {"sensor_drift": EFFECTS["sensor_drift"].values(np.zeros(0), np.zeros(0), None, {})}}
    assert apply_to_spec(spec, params, include_urdf_effects=True).to_xml() == before
    assert calibration_from_params(params) == {}
    assert identification_effects(["viscous_friction", "sensor_drift"]) == ["viscous_friction"]
    assert EFFECTS["sensor_drift"].sensor_side and not EFFECTS["sensor_drift"].in_urdf

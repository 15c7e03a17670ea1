"""A position ripple (effects/position_ripple.py): its period found by the position-domain periodogram, the
periodogram the least squares it stands for, and what the assets and the excitation design do with it.

The loop on the lab's ``ripple`` arm is tests/test_trustworthy_loop.py's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from sim2real.excitation.config import identification_effects
from sim2real.identification.effects import EFFECTS, apply_to_spec, calibration_from_params
from sim2real.identification.effects.position_ripple import (
    DEFAULT_PERIOD, OVERSAMPLING, best_periods, position_periodogram, search_frequencies,
)

RATE = 200.0


def motion(seed: int, joints: int = 3, duration: float = 20.0) -> np.ndarray:
    """Positions of a few incommensurate sinusoids per joint (an excitation's kind of motion), (N, joints)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / RATE)
    q = np.zeros((t.size, joints))
    for j in range(joints):
        for w in 2 * np.pi * rng.uniform(0.08, 0.5, size=3):
            q[:, j] += rng.uniform(0.2, 0.5) * np.sin(w * t + rng.uniform(0, 2 * np.pi))
    return q


@settings(max_examples=25, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**16), period=st.floats(0.04, 0.5), amplitude=st.floats(0.05, 1.0),
       phase=st.floats(-np.pi, np.pi), joint=st.integers(0, 2))
def test_the_search_finds_a_ripples_period_on_its_joint_alone(seed, period, amplitude, phase, joint):
    """A ripple of any period the motion resolves, on one joint, under noise a tenth of it or more: the search's
    period is the true one to within the grid's step, its joint's gain is most of the ripple's energy, and the
    other joints' gains are the noise's (under a tenth of the ripple's)."""
    q = motion(seed)
    grid = search_frequencies(q[:, joint])
    assume(grid.min() <= 1.0 / period <= grid.max())  # a period the motion resolves (the next test: which)
    rng = np.random.default_rng(seed + 1)
    residual = 0.1 * amplitude * rng.normal(size=q.shape)
    ripple = amplitude * np.sin(2 * np.pi * q[:, joint] / period + phase)
    residual[:, joint] += ripple
    periods, gains = best_periods(q, residual)
    step = 1.0 / (OVERSAMPLING * np.ptp(q[:, joint]))
    assert abs(1.0 / periods[joint] - 1.0 / period) <= step, (periods[joint], period)
    energy = float(np.sum((ripple - ripple.mean()) ** 2))
    assert gains[joint] > 0.8 * energy
    assert all(gains[k] < 0.1 * energy for k in range(3) if k != joint)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**16), samples=st.integers(8, 400))
def test_the_periodogram_is_the_least_squares_of_one_sinusoid_and_an_offset(seed, samples):
    """Each frequency's gain is what least squares on [sin, cos, 1] of the position removes from the residual,
    the grid's rotations turned step by step included."""
    rng = np.random.default_rng(seed)
    q = np.sort(rng.uniform(-2.0, 1.0, samples))
    y = rng.normal(size=samples) + 0.5 * np.sin(7.0 * q)
    frequencies = 0.3 + 0.17 * np.arange(60)
    gains = position_periodogram(q, y, frequencies)
    centred = y - y.mean()
    for f, gain in zip(frequencies, gains, strict=True):
        design = np.column_stack([np.sin(2 * np.pi * f * q), np.cos(2 * np.pi * f * q), np.ones(samples)])
        fitted = design @ np.linalg.lstsq(design, y, rcond=None)[0]
        expected = float(centred @ centred - np.sum((y - fitted) ** 2))
        assert gain == pytest.approx(expected, rel=1e-7, abs=1e-9 * float(centred @ centred))


def test_a_joint_that_hardly_moves_resolves_no_period():
    """Under two periods of the shortest ripple over its excursion, a joint has no grid: it keeps the default
    period and gives nothing; a log too coarse for the short periods resolves only the long ones."""
    q = motion(3)
    q[:, 1] = 0.3 + 1e-4 * q[:, 1]
    residual = np.random.default_rng(0).normal(size=q.shape)
    periods, gains = best_periods(q, residual)
    assert search_frequencies(q[:, 1]).size == 0
    assert periods[1] == DEFAULT_PERIOD and gains[1] == 0.0
    coarse = search_frequencies(q[::20, 0])  # 10 Hz: every step is long, so the shortest period is too
    assert 0 < coarse.size < search_frequencies(q[:, 0]).size and 1.0 / coarse.max() > 1.0 / search_frequencies(q[:, 0]).max()


def test_the_assets_and_the_design_leave_a_ripple_out():
    """MuJoCo and URDF have no torque periodic in a position: the calibrated MJCF and the calibration get nothing
    (the simulation lacks it, as method.md says); the excitation design does not aim at its columns (their period
    is not known before the fit), so a model.yaml line adding it reruns no design."""
    import mujoco

    spec = mujoco.MjSpec.from_string("<mujoco><worldbody><body><joint name='j' damping='0.1'/>"
                                     "<geom size='0.1'/></body></worldbody></mujoco>")
    before = spec.to_xml()
    values = {"amplitude": {"j": 0.3}, "phase": {"j": 0.0}, "period": {"j": 0.2}}
    params = {"effects": {"position_ripple": values}}
    assert apply_to_spec(spec, params, include_urdf_effects=True).to_xml() == before
    assert calibration_from_params(params) == {}
    assert identification_effects(["link_inertia", "viscous_friction", "position_ripple"]) == ["viscous_friction"]
    assert not EFFECTS["position_ripple"].in_design and EFFECTS["viscous_friction"].in_design


def test_the_screen_credits_a_ripple_on_positions_the_fit_never_visited_and_not_a_smooth_error():
    """The diagnosis's screen (diagnosis.screens.ripple_gain): period and coefficients from the fit run, judged on a
    holdout run that partly moves elsewhere. A ripple (a period no whole fraction of a turn) is credited with most of
    its energy there; a smooth error of the pose (a bent gravity term), which a sinusoid fitted on the fit run can
    mimic only where the fit run went, with under half of its own (a screen is generous: the trial, every
    coefficient refitted beside the ripple's, decides)."""
    from sim2real.identification.diagnosis.screens import ripple_gain

    fit_q, holdout_q = motion(1), motion(2) + 0.3
    rng = np.random.default_rng(5)
    noise = [0.02 * rng.normal(size=fit_q.shape) for _ in range(2)]
    ripple = [0.3 * np.sin(2 * np.pi * q / 0.23) for q in (fit_q, holdout_q)]
    gain = ripple_gain(fit_q, ripple[0] + noise[0], holdout_q, ripple[1] + noise[1])
    assert np.all(gain > 0.9 * np.sum(ripple[1] ** 2, axis=0)), gain / np.sum(ripple[1] ** 2, axis=0)
    bend = [0.4 * np.cos(q) for q in (fit_q, holdout_q)]
    gain = ripple_gain(fit_q, bend[0] + noise[0], holdout_q, bend[1] + noise[1])
    energy = np.sum((bend[1] - bend[1].mean(axis=0)) ** 2, axis=0)
    assert np.all(gain < 0.5 * energy), gain / energy


def test_a_long_log_is_searched_on_fewer_samples_for_the_periods_every_sample_resolves():
    """A 100 s log at 200 Hz (20 000 samples) is searched on 4 000 of them, evenly spaced: every fifth sample alone
    would resolve no period shorter than four of its own steps, but in the position domain the samples fall anywhere
    in a period, so the search keeps the periods the whole log resolves and finds a short ripple there."""
    q = motion(7, joints=1, duration=100.0)
    period = 1.5 / search_frequencies(q[:, 0]).max()  # short: resolved by the log, not by every fifth sample
    assert 1.0 / period > search_frequencies(q[::5, 0]).max()
    residual = 0.2 * np.sin(2 * np.pi * q / period) + 0.02 * np.random.default_rng(1).normal(size=q.shape)
    periods, _ = best_periods(q, residual)
    assert periods[0] == pytest.approx(period, rel=0.01)

"""The model-free ceiling says what kind of thing is left (issue 30 item 4), on residuals whose cause is known.

Each case builds the last rung's residual on a fit run and a holdout run of a smooth multi-joint motion: white
noise at the floor plus one kind of unexplained torque, which :func:`model_free_ceiling` must classify from the
runs alone: a function of the motion the library lacks (a cogging ripple in one joint's position), a drift with
time within each run (a warm-up), an offset per run, hysteresis (a torque that follows the displacement since
the last reversal), or nothing above the floor.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.identification.diagnosis import model_free_ceiling as ceiling_data
from sim2real.report.verdicts import ceiling_section
from sim2real.identification.diagnosis.ceiling import since_reversal
from sim2real.identification.fitting import TorqueData

JOINTS = ["j1", "j2", "j3"]
FLOOR = 0.05
RATE = 100.0


def motion(seed: int, duration: float = 20.0, trend: float = 0.0) -> tuple[np.ndarray, ...]:
    """A few incommensurate sinusoids per joint: positions, velocities, accelerations; ``trend`` (rad/s): the first
    joint also moves steadily through the run, so that its position follows the run's time."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / RATE)
    q, qd, qdd = (np.zeros((t.size, len(JOINTS))) for _ in range(3))
    for j in range(len(JOINTS)):
        for w in 2 * np.pi * rng.uniform(0.08, 0.6, size=3):
            a, phase = rng.uniform(0.2, 0.6), rng.uniform(0, 2 * np.pi)
            q[:, j] += a * np.sin(w * t + phase)
            qd[:, j] += a * w * np.cos(w * t + phase)
            qdd[:, j] -= a * w**2 * np.sin(w * t + phase)
    q[:, 0] += trend * t
    qd[:, 0] += trend
    return t, q, qd, qdd


def model_free_ceiling(*args, **options) -> dict:
    """The ceiling's document with the words the report gives it (``text``)."""
    return ceiling_section(ceiling_data(*args, **options), "{robot}")


def data(name: str, seed: int, residual_of, trend: float = 0.0) -> tuple[TorqueData, np.ndarray]:
    t, q, qd, qdd = motion(seed, trend=trend)
    noise = FLOOR * np.random.default_rng(seed + 100).normal(size=q.shape)
    residual = noise + residual_of(t, q, qd, seed)
    torque = TorqueData(JOINTS, t, q, qd, qdd, residual, [slice(0, t.size)], [name], "tau", False,
                        np.full(len(JOINTS), FLOOR))
    return torque, residual


def ceiling(residual_of, noise_floor_factor: float = 1.5, trend: float = 0.0) -> dict:
    fit, fit_residual = data("fit", 1, residual_of, trend)
    holdout, holdout_residual = data("holdout", 2, residual_of, trend)
    return model_free_ceiling(fit, fit_residual, holdout, holdout_residual, noise_floor_factor)


def on_joint(j: int, values: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape)
    out[:, j] = values
    return out


def test_a_cogging_ripple_is_a_function_of_the_motion_the_library_lacks():
    result = ceiling(lambda t, q, qd, seed: on_joint(1, 0.4 * np.sin(2 * np.pi * q[:, 1] / 0.5), q.shape))
    row = result["per_joint"]["j2"]
    assert row["kind"] == "motion", row
    assert row["ceiling_rmse"] < 0.6 * row["rung_rmse"], "the learner explains most of the ripple on the holdout"
    # its period found by the search on the fit runs (0.5 rad is no whole fraction of a turn: the integer harmonics
    # would part from it beyond the positions the fit run visited)
    assert row["learner"] == "a ripple of the searched period", row
    text = row["gains_most_with"][0]
    assert text.startswith("position of j2 (periodic, every ") and text.endswith(" rad)"), text
    assert float(text.split("every ")[1].split(" rad")[0]) == pytest.approx(0.5, rel=0.05)
    assert result["per_joint"]["j1"]["kind"] == result["per_joint"]["j3"]["kind"] == "at_floor"
    assert "lacks an effect that is a function of the motion" in result["text"] and "j2" in result["text"]
    assert result["torque_rmse"]["per_joint"]["j2"] == row["ceiling_rmse"]


def test_a_warm_up_drift_is_not_the_motion_but_time_within_each_run():
    def warm_up(t, q, qd, seed):
        level = 0.3 if seed == 1 else -0.25  # each run warms up towards its own offset
        return on_joint(0, level * (1 - np.exp(-t / 6.0)), q.shape)

    result = ceiling(warm_up)
    row = result["per_joint"]["j1"]
    assert row["kind"] == "not_motion", row
    assert row["follows"] == "time", row["beyond_motion"]
    assert row["beyond_motion"]["time"] > 0.8 and row["beyond_motion"]["time"] > row["beyond_motion"]["run"]
    assert "No function of the motion explains the rest" in result["text"] and "drifts with time" in result["text"]
    # no property of the robot, but the fits take it for one: the user is told what to do about it
    assert "On j1 the torque sits at an offset of its own in each run or drifts within it" in result["text"]
    assert "torque sensors zeroed at rest" in result["text"]


def test_a_drift_the_motion_imitates_is_named_a_drift_not_an_effect_to_model():
    """One excitation run after run: a joint's position follows each run's time, so a learner on the motion takes
    a warm-up for a function of that position; a drift within each run removes more of it, and is named."""
    def warm_up(t, q, qd, seed):
        return on_joint(0, 0.3 * (1 - np.exp(-t / 6.0)), q.shape)

    result = ceiling(warm_up, trend=0.05)
    row = result["per_joint"]["j1"]
    assert row["kind"] == "motion" and row["ceiling_rmse"] < 0.6 * row["rung_rmse"], row
    assert row["follows"] == "time" and row["imitated"], row
    assert row["beyond_motion"]["time"] >= row["explained_beyond_noise"], row
    assert "Model that dependence" not in result["text"] and "only imitates a drift: j1" in result["text"]
    assert "On j1 the torque sits at an offset of its own in each run or drifts within it" in result["text"]
    assert result["declare"]["joints"] == ["j1"]

    # with a ripple beside the warm-up, the learners fitted again on each run's residual less its drift still find
    # the ripple: both are named, the ripple to model and the drift to declare
    both = ceiling(lambda t, q, qd, seed: on_joint(
        0, 0.3 * (1 - np.exp(-t / 6.0)) + 0.1 * np.sin(2 * np.pi * q[:, 0] / 0.5), q.shape), trend=0.05)
    row = both["per_joint"]["j1"]
    assert row["kind"] == "motion" and row["follows"] == "time" and not row["imitated"], row
    assert "Model that dependence" in both["text"] and "beside a drift of each run's own" in both["text"]
    assert both["declare"]["joints"] == ["j1"]

    # a ripple of the position stays the motion's where the position follows the time as much
    ripple = ceiling(lambda t, q, qd, seed: on_joint(0, 0.4 * np.sin(2 * np.pi * q[:, 0] / 0.5), q.shape),
                     trend=0.05)
    row = ripple["per_joint"]["j1"]
    assert row["kind"] == "motion" and "follows" not in row, row
    assert "Model that dependence" in ripple["text"] and "declare" not in ripple


def test_an_offset_per_run_is_named_as_such():
    result = ceiling(lambda t, q, qd, seed: on_joint(2, np.full(t.size, 0.2 if seed == 1 else -0.2), q.shape))
    row = result["per_joint"]["j3"]
    assert row["kind"] == "not_motion" and row["follows"] == "run", row
    assert "On j3 the torque sits at an offset of its own" in result["text"]


def test_hysteresis_follows_the_displacement_since_the_last_reversal():
    def dahl(t, q, qd, seed):
        displacement = since_reversal(q, qd, [slice(0, t.size)])[:, 0]
        return on_joint(0, 0.3 * np.sign(qd[:, 0]) * (1 - np.exp(-np.abs(displacement) / 0.05)), q.shape)

    result = ceiling(dahl)
    row = result["per_joint"]["j1"]
    assert "offset of its own" not in result["text"], "hysteresis is the robot's: no advice to zero a sensor"
    # a function of the history, which the motion now only partly reveals: either the learner gets most of it
    # (the sign of the velocity), or what is left follows the history since the reversal
    assert row["kind"] in ("motion", "not_motion") and row["kind"] != "at_floor"
    if row["kind"] == "not_motion":
        assert row["follows"] == "history", row["beyond_motion"]


def test_white_noise_at_the_floor_leaves_nothing_to_explain():
    result = ceiling(lambda t, q, qd, seed: np.zeros_like(q))
    assert {row["kind"] for row in result["per_joint"].values()} == {"at_floor"}
    assert not any(row["fitted"] for row in result["per_joint"].values()), "no learner where nothing is left"
    assert result["text"] == ""
    # made to look anyway, the learner finds nothing in white noise that carries over to the holdout run
    forced = ceiling(lambda t, q, qd, seed: np.zeros_like(q), noise_floor_factor=0.0)
    for row in forced["per_joint"].values():
        assert row["fitted"] and row["ceiling_rmse"] >= 0.97 * row["rung_rmse"], row
        assert row["ceiling_rmse"] == pytest.approx(FLOOR, rel=0.15)


def test_since_reversal_restarts_at_every_change_of_direction():
    q = np.array([[0.0], [1.0], [2.0], [1.5], [0.5], [1.0]])
    qd = np.array([[1.0], [1.0], [1.0], [-1.0], [-1.0], [1.0]])
    assert since_reversal(q, qd, [slice(0, 6)])[:, 0].tolist() == [0.0, 1.0, 2.0, 0.0, -1.0, 0.0]


def test_a_joint_without_a_measured_floor_is_judged_in_the_arms_units_as_the_ladder_does():
    """A joint whose torque shows no white noise (floor 0) is judged against the floor the ladder uses
    (fitting.judged_floors), never divided by zero: its row has numbers and the text says what is left."""
    from sim2real.identification.fitting import judged_floors

    fit, fit_residual = data("fit", 1, lambda t, q, qd, seed: on_joint(2, 0.5 * (1 - np.exp(-t / 6.0)), q.shape))
    holdout, holdout_residual = data("holdout", 2, lambda t, q, qd, seed: on_joint(2, -0.4 * (1 - np.exp(-t / 6.0)), q.shape))
    for torque in (fit, holdout):
        torque.noise_floor[2] = 0.0
    result = model_free_ceiling(fit, fit_residual, holdout, holdout_residual)
    row = result["per_joint"]["j3"]
    floor = judged_floors(holdout.noise_floor)[2]
    assert floor == pytest.approx(0.2 * np.sqrt(2 * FLOOR**2 / 3))
    assert row["rung_x_floor"] == pytest.approx(row["rung_rmse"] / floor, rel=1e-3) and row["kind"] == "not_motion"
    assert "j3 (" in result["text"] and "x its floor" in result["text"]

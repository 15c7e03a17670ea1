"""The model-free ceiling carries a function of the pose to the holdout's poses and names it; a friction that changes
with time stays "not the motion"."""

from __future__ import annotations

import numpy as np

from sim2real.identification import fitting, sysid
from sim2real.identification.diagnosis import model_free_ceiling
from sim2real.identification.fitting import FitContext
from sim2real.report.verdicts import ceiling_section
from sysid_lab import FAST_FIT
from test_model_free_ceiling import data as synthetic_data
from test_model_free_ceiling import on_joint


class LevelArm:
    """The nominal model's gravity as the ceiling reads it, for the synthetic three-joint arm: none (its joints'
    axes are vertical), so what is left can only follow the pose through the angles themselves."""

    @staticmethod
    def gravity(q: np.ndarray) -> np.ndarray:
        return np.zeros_like(q)

    @staticmethod
    def unit_gravity(q: np.ndarray) -> np.ndarray:
        return np.zeros((*q.shape, 3))


def test_a_pull_that_follows_another_joints_angle_is_a_function_of_the_pose_named_by_that_angle():
    """A torque on j3 that follows the angle of j1 (a hose dragged by the base joint): the trees on the motion do not
    carry it to the holdout's poses, the ridge on the pose does, and the report names the angle."""
    def pull(t, q, qd, seed):
        return on_joint(2, 0.4 * np.sin(q[:, 0]), q.shape)

    fit, fit_residual = synthetic_data("fit", 1, pull)
    holdout, holdout_residual = synthetic_data("holdout", 2, pull)
    result = ceiling_section(model_free_ceiling(fit, fit_residual, holdout, holdout_residual, 1.5,
                                                nominal_dynamics=LevelArm()), "{robot}")
    row = result["per_joint"]["j3"]
    assert row["kind"] == "motion" and row["learner"] == "a ridge regression on the pose", row
    assert row["ceiling_rmse"] < 0.5 * row["rung_rmse"], row
    assert "the sine of the angle of j1" in row["gains_most_with"], row["gains_most_with"]
    assert "A function of the pose alone explains much of what is left" in result["text"]
    assert "No effect of the library has its shape" in result["text"] and "base_mount" not in result["text"]


def test_a_friction_that_eases_as_the_joint_warms_is_not_the_motion_on_any_joint_left(shared_lab):
    """real_arm_like_warming: the dry friction is 60 % above its warm level at each run's start and settles over 6 s.
    With load_friction in the model (whose load learner can fit part of a level that changes), the ceiling reads "not
    the motion" on every joint left above its floor."""
    fit_data, holdout_data = shared_lab.data("real_arm_like_warming")
    context = FitContext.on_nominal(shared_lab.nominal, fit_data, holdout_data,
                                    {**fitting.DEFAULT_SETTINGS, **FAST_FIT})
    side = sysid.fit_ladder(["link_inertia", "load_friction", "rotor_inertia"], context, diagnosed=False)
    result = model_free_ceiling(fit_data, side.fit_residual, holdout_data, side.holdout_residual, 1.5,
                                nominal_dynamics=shared_lab.nominal.dynamics)
    left = {j: row for j, row in result.per_joint.items() if row.kind != "at_floor"}
    assert left, "the warming leaves something above the floor"
    assert all(row.kind == "not_motion" for row in left.values()), {j: (r.kind, r.learner) for j, r in left.items()}
    assert result.points_to is None

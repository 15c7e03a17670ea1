"""A real consumer of the USD: NVIDIA Newton (CPU) loads it and holds the Panda like MuJoCo does.

Newton is an optional extra (`pip install -e '.[newton]'`); the test skips only when it cannot be imported.
Tolerance: over 1 s of holding the home pose under gravity, every arm joint of Newton stays within
1e-3 rad of MuJoCo's (the sag itself is ~7e-3 rad on joint 2), and the final sag agrees within 10 %.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from collision_usd_build import ROBOT
from sim2real.assets.equivalence import hold_in_mujoco, hold_in_newton
from sim2real.assets.urdf_model import read_urdf

newton = pytest.importorskip("newton", reason="NVIDIA Newton is not installed: pip install -e '.[newton]'")
pytest.importorskip("newton_usd_schemas", reason="Newton's USD importer needs newton-usd-schemas: pip install -e '.[newton]'")

ARM = [f"panda_joint{i}" for i in range(1, 8)]
DURATION_S = 1.0
DT_S = 4e-4
TRAJECTORY_TOL_RAD = 1e-3
SAG_REL_TOL = 0.10


@pytest.fixture(scope="module")
def built(built_tree: Path) -> Path:
    """The suite's shared built tree (conftest): read-only."""
    return built_tree


@pytest.fixture(scope="module")
def newton_model(built: Path):  # noqa: ANN201 (newton.Model)
    builder = newton.ModelBuilder()
    builder.add_usd(str(built / "results" / ROBOT / "usd" / f"{ROBOT}.usda"), floating=False)
    return builder.finalize(device="cpu")


def test_newton_imports_joints_masses_limits_and_gains(built: Path, newton_model) -> None:  # noqa: ANN001
    urdf = read_urdf(built / "results" / ROBOT / f"{ROBOT}.urdf")
    labels = [label.rsplit("/", 1)[-1] for label in newton_model.joint_label]
    movable = [j for j in urdf.joints.values() if j.type != "fixed"]
    assert newton_model.joint_dof_count == len(movable) == 9
    masses = dict(zip((label.rsplit("/", 1)[-1] for label in newton_model.body_label), newton_model.body_mass.numpy(), strict=True))
    for name, link in urdf.links.items():
        if link.mass > 0:
            assert masses[name] == pytest.approx(link.mass, rel=1e-6), name
    dof_start = newton_model.joint_qd_start.numpy()
    lower, upper = newton_model.joint_limit_lower.numpy(), newton_model.joint_limit_upper.numpy()
    ke = newton_model.joint_target_ke.numpy()
    config = yaml.safe_load((built / "configs" / ROBOT / "robot.yaml").read_text())
    for joint in movable:
        dof = dof_start[labels.index(joint.name)]
        assert (lower[dof], upper[dof]) == pytest.approx((joint.lower, joint.upper), abs=1e-5), joint.name
    # Newton converts USD's per-degree stiffness back to per-radian: the MJCF's kp
    assert ke[dof_start[labels.index("panda_joint1")]] == pytest.approx(config["actuators"][0]["kp"], rel=1e-5)


def test_newton_holds_the_pose_like_mujoco(built: Path) -> None:
    results = built / "results" / ROBOT
    home = yaml.safe_load((built / "configs" / ROBOT / "robot.yaml").read_text())["home"]
    in_newton = hold_in_newton(results / "usd" / f"{ROBOT}.usda", home, ARM, DURATION_S, DT_S)
    in_mujoco = hold_in_mujoco(results / "mjcf" / "scene.xml", ARM, DURATION_S, DT_S)
    assert in_newton.q.shape == in_mujoco.q.shape == (round(DURATION_S / 0.01), len(ARM))
    assert np.all(np.isfinite(in_newton.q))
    np.testing.assert_allclose(in_newton.q0, in_mujoco.q0, atol=1e-6)
    deviation = np.abs(in_newton.q - in_mujoco.q).max(axis=0)
    assert deviation.max() < TRAJECTORY_TOL_RAD, dict(zip(ARM, deviation.round(5), strict=True))
    sag_newton, sag_mujoco = in_newton.q[-1] - in_newton.q0, in_mujoco.q[-1] - in_mujoco.q0
    loaded = np.abs(sag_mujoco) > 1e-3  # joints that gravity actually loads at home (2, 4, 6)
    assert loaded.sum() >= 2 and abs(sag_mujoco[1]) < 0.05  # it holds the pose, with a visible sag
    np.testing.assert_allclose(sag_newton[loaded], sag_mujoco[loaded], rtol=SAG_REL_TOL)

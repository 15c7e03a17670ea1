"""Cross-format equivalence of URDF, MJCF and USD: passes on the build, names what differs otherwise."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from collision_usd_build import ROBOT
from sim2real.assets.equivalence import check_equivalence, mjcf_facts, urdf_facts, usd_facts
from sim2real.errors import InputError

from pxr import Usd, UsdPhysics  # noqa: E402


@pytest.fixture(scope="module")
def built(built_tree: Path) -> Path:
    """The suite's shared built tree (conftest): read-only."""
    return built_tree


def paths(tree: Path) -> tuple[Path, Path, Path]:
    results = tree / "results" / ROBOT
    return results / f"{ROBOT}.urdf", results / "mjcf" / f"{ROBOT}.xml", results / "usd" / f"{ROBOT}.usda"


def usd_copy(built: Path, tmp_path: Path) -> Path:
    """A writable copy of the USD pair (the geometry layer is referenced by a relative path)."""
    target = tmp_path / "usd"
    shutil.copytree(built / "results" / ROBOT / "usd", target)
    return target / f"{ROBOT}.usda"


def test_build_writes_the_equivalence_report(built: Path) -> None:
    report = json.loads((built / "results" / ROBOT / "equivalence.json").read_text())
    assert report["equivalent"] is True
    assert [j["name"] for j in report["joints"]] == [f"panda_joint{i}" for i in range(1, 8)] + ["panda_finger_joint1", "panda_finger_joint2"]
    joint1 = report["drives"]["panda_joint1"]
    assert joint1["usd_stiffness"] == pytest.approx(joint1["kp"] * 3.141592653589793 / 180, rel=1e-6)
    assert report["joints"][0]["usd_limits_usd_units"] == pytest.approx([-166.0031, 166.0031], abs=1e-3)


def test_formats_agree_fact_by_fact(built: Path) -> None:
    urdf, mjcf, usd = (f(p) for f, p in zip((urdf_facts, mjcf_facts, usd_facts), paths(built), strict=True))
    assert urdf.joints == mjcf.joints == usd.joints
    assert set(urdf.masses) == set(mjcf.masses) == set(usd.masses)
    assert set(mjcf.gains) == set(usd.gains) == {f"panda_joint{i}" for i in range(1, 8)} | {"panda_finger_joint1"}


def test_drive_gain_without_degree_conversion_fails_naming_the_joint(built: Path, tmp_path: Path) -> None:
    usd_path = usd_copy(built, tmp_path)
    stage = Usd.Stage.Open(str(usd_path))
    drive = UsdPhysics.DriveAPI(stage.GetPrimAtPath("/panda/joints/panda_joint4"), "angular")
    drive.GetStiffnessAttr().Set(3500.0)  # the per-rad value written as per-degree: the 57x error
    stage.GetRootLayer().Save()
    urdf, mjcf, _ = paths(built)
    with pytest.raises(InputError, match=r"joint 'panda_joint4' drive stiffness"):
        check_equivalence(urdf, mjcf, usd_path, tmp_path / "equivalence.json")
    assert not (tmp_path / "equivalence.json").exists()


def test_mass_and_limit_mismatches_name_the_link_and_joint(built: Path, tmp_path: Path) -> None:
    usd_path = usd_copy(built, tmp_path)
    stage = Usd.Stage.Open(str(usd_path))
    UsdPhysics.MassAPI(stage.GetPrimAtPath("/panda/panda_link3")).GetMassAttr().Set(3.0)
    UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/panda/joints/panda_joint6")).GetUpperLimitAttr().Set(3.7525)  # radians, not degrees
    stage.GetRootLayer().Save()
    urdf, mjcf, _ = paths(built)
    with pytest.raises(InputError) as error:
        check_equivalence(urdf, mjcf, usd_path)
    assert "link 'panda_link3' mass" in str(error.value)
    assert "joint 'panda_joint6' limits" in str(error.value)

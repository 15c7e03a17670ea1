"""The user's loop on the Panda demo, end to end through Snakemake (issues 4 and 5, "Done when").

From a copy of the repository with an empty ladder: `snakemake results/panda/gap.json` builds the
lab data and the report, which names `coulomb_friction` first. Adding that one line to
configs/panda/model.yaml and running again makes the holdout torque RMSE fall by at least 80%, and
the calibrated MJCF carries the identified friction.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import mujoco
import pytest
import yaml

from buildtree import copy_repo, make_fast, rules_run, run_snakemake

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def _set_effects(tree: Path, effects: list[str]) -> None:
    path = tree / "configs" / "panda" / "model.yaml"
    data = yaml.safe_load(path.read_text()) or {}
    data["effects"] = effects
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def test_diagnose_add_one_line_refit_and_calibrate(tmp_path: Path) -> None:
    tree = copy_repo(ROOT, tmp_path / "repo")
    make_fast(tree)
    _set_effects(tree, [])

    log = run_snakemake(tree, "results/panda/gap.json")
    assert "lab_run" in rules_run(log), "the gap report builds the lab data it compares with"
    gap = json.loads((tree / "results/panda/gap.json").read_text())
    top = gap["diagnosis"]["candidates"][0]
    assert top["effect"] == "coulomb_friction"
    assert top["add"] == "- coulomb_friction"
    assert "configs/panda/model.yaml" in gap["diagnosis"]["verdict"]
    md = (tree / "results/panda/gap.md").read_text()
    assert "coulomb_friction" in md and "![Model ladder]" in md
    # Where it fails: friction acts in slow motion and at velocity reversals.
    assert gap["where"]["summary"]["regimes"][0] == "slow_reversal"

    nominal_report = tmp_path / "base_gap.json"
    nominal_report.write_bytes((tree / "results/panda/gap.json").read_bytes())

    _set_effects(tree, ["coulomb_friction"])
    log = run_snakemake(tree, "results/panda/gap.json", "results/panda/calibrated/mjcf/panda.xml")
    assert "lab_run" not in rules_run(log), "editing the model does not rebuild the measurements"
    ladder = json.loads((tree / "results/panda/gap.json").read_text())["ladder"]
    assert [r["effects"] for r in ladder] == [[], ["coulomb_friction"]]
    before = ladder[0]["metrics"]["torque_rmse"]["overall"]
    after = ladder[1]["metrics"]["torque_rmse"]["overall"]
    assert after <= 0.2 * before, f"holdout torque RMSE {before:.4f} -> {after:.4f} N m"
    # Replayed with the identified friction, the arm also follows the measured positions more closely.
    positions = [r["metrics"]["position_rmse"]["overall"] for r in ladder]
    assert positions[1] < 0.5 * positions[0], positions

    # What a reviewer reads in the pull request that adds the line.
    diff = subprocess.run(
        [sys.executable, "-m", "sim2real.cli", "gap-diff", str(nominal_report), str(tree / "results/panda/gap.json")],
        check=True, capture_output=True, text=True,
    ).stdout
    assert "| + coulomb_friction | – |" in diff and "new |" in diff
    assert "base: `coulomb_friction`" in diff

    identified = ladder[1]["params"]["coulomb_friction"]["friction"]
    model = mujoco.MjModel.from_xml_path(str(tree / "results/panda/calibrated/mjcf/panda.xml"))
    for joint, value in identified.items():
        dof = model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]
        assert model.dof_frictionloss[dof] == pytest.approx(value, rel=1e-4, abs=1e-5), joint
    nominal = mujoco.MjModel.from_xml_path(str(tree / "results/panda/mjcf/panda.xml"))
    assert not (nominal.dof_frictionloss[:7] > 0.1).any(), "the nominal MJCF stays nominal"

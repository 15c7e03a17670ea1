"""End to end in a tmp copy of the project: the asset DAG reruns exactly what an edit affects.

(The calibrated tree, built by the same rules from identified values, is exercised end to end in
tests/test_demo_loop.py.)"""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import pytest

from buildtree import edit_yaml, rules_run
from buildtree import run_snakemake as snakemake
from readme import copy_built

pytestmark = pytest.mark.slow

ROBOT = "ur5"  # the other robot than test_build_cache's edit; nothing here is robot-specific
TARGETS = [f"results/{ROBOT}/{ROBOT}.urdf", f"results/{ROBOT}/mjcf/{ROBOT}.xml", f"results/{ROBOT}/mjcf/scene.xml"]
MESH_RULES = {"visual_mesh", "collision_mesh", "coacd"}  # mesh conversion and convex decomposition


def jobs_outputs(log: str) -> list[str]:
    """The outputs of the jobs a Snakemake log lists (each job's ``output:`` line, its files comma-separated)."""
    return [path.strip() for line in re.findall(r"^\s+output: (.+)$", log, flags=re.MULTILINE)
            for path in line.split(",")]


def mesh_outputs(tree: Path) -> dict[str, float]:
    meshes = tree / "results" / ROBOT / "meshes"
    return {str(p.relative_to(meshes)): p.stat().st_mtime_ns for p in sorted(meshes.rglob("*")) if p.is_file()}


def test_inertial_edit_reruns_urdf_and_mjcf_only_then_nothing(tmp_path: Path, built_tree: Path) -> None:
    # A copy of the suite's shared tree, built cold (meshes, decomposition and all) by `snakemake all`.
    tree = copy_built(built_tree, tmp_path / "project")
    assert "Nothing to be done" in snakemake(tree, "-n", *TARGETS)
    meshes_before = mesh_outputs(tree)
    assert any(name.endswith(".obj") for name in meshes_before) and any(name.endswith(".stl") for name in meshes_before)

    xacro = tree / "robots" / ROBOT / f"{ROBOT}.urdf.xacro"
    text = xacro.read_text()
    assert 'name="shoulder_link" mesh="shoulder" mass="3.7"' in text
    xacro.write_text(text.replace('name="shoulder_link" mesh="shoulder" mass="3.7"', 'name="shoulder_link" mesh="shoulder" mass="3.9"'))

    dry = snakemake(tree, "-n", *TARGETS)
    assert "urdf" in rules_run(dry) and not (rules_run(dry) & MESH_RULES)
    after_edit = rules_run(snakemake(tree, *TARGETS))
    assert after_edit == {"urdf", "mjcf"}
    assert mesh_outputs(tree) == meshes_before
    model = mujoco.MjModel.from_xml_path(str(tree / "results" / ROBOT / "mjcf" / "scene.xml"))
    assert model.body_mass[model.body("shoulder_link").id] == pytest.approx(3.9)

    assert "Nothing to be done" in snakemake(tree, "-n", *TARGETS)
    assert rules_run(snakemake(tree, *TARGETS)) == set()


def test_robot_yaml_edits_rerun_what_reads_the_setting(tmp_path: Path, built_tree: Path) -> None:
    """robot.yaml reaches the MJCF, USD, fits and excitation as params of the settings they read, not as a file: a
    comment reruns nothing, a collision tolerance only the collision report, an armature the MJCF and what follows
    it, never the meshes."""
    tree = copy_built(built_tree, tmp_path / "project")
    targets = [*TARGETS, f"results/{ROBOT}/usd/{ROBOT}.usda", f"results/{ROBOT}/collision/report.json"]
    config = tree / "configs" / ROBOT / "robot.yaml"
    shipped = config.read_text()
    assert "Nothing to be done" in snakemake(tree, "-n", *targets)

    config.write_text(shipped + "# a comment changes no setting\n")
    assert "Nothing to be done" in snakemake(tree, "-n", *targets)

    edit_yaml(config, lambda robot: robot["collision"]["tolerance"].update(hausdorff_mm=16.0))
    assert rules_run(snakemake(tree, "-n", *targets)) == {"collision_report"}

    config.write_text(shipped)
    edit_yaml(config, lambda robot: robot.update(armature={"*": 0.12}))
    rerun = rules_run(snakemake(tree, "-n", *targets))
    assert {"mjcf", "usd"} <= rerun and not rerun & (MESH_RULES | {"urdf", "collision_report"})

    config.write_text(shipped)
    assert "Nothing to be done" in snakemake(tree, "-n", *targets)


DESIGN = "results/panda/excitation/identification.csv"


def _built_copy_with_config(tmp_path: Path, built_tree: Path, name: str) -> tuple[Path, Path, str]:
    """A copy of the built tree, the Panda's config ``name`` in it and its shipped text; the design up to date."""
    tree = copy_built(built_tree, tmp_path / "project")
    config = tree / "configs" / "panda" / name
    assert "Nothing to be done" in snakemake(tree, "-n", DESIGN)
    return tree, config, config.read_text()


def test_model_yaml_edits_rerun_the_excitation_only_when_its_effects_change(tmp_path: Path, built_tree: Path) -> None:
    """The excitation design reads model.yaml's effects as a param, those it identifies: a comment, a fit setting or an
    effect without columns of its own reruns no design; an effect it identifies does; an unknown effect stops the run
    before any job, naming the file."""
    tree, model, shipped = _built_copy_with_config(tmp_path, built_tree, "model.yaml")

    model.write_text(shipped + "# a comment changes no effect\n")
    assert "Nothing to be done" in snakemake(tree, "-n", DESIGN)
    edit_yaml(model, lambda config: config.setdefault("fit", {}).update(bootstrap_replicates=7))
    assert "Nothing to be done" in snakemake(tree, "-n", DESIGN)

    edit_yaml(model, lambda config: config.update(effects=[*config["effects"], "payload", "actuation_delay"]))
    assert "Nothing to be done" in snakemake(tree, "-n", DESIGN)  # no column of their own to identify
    edit_yaml(model, lambda config: config.update(effects=[*config["effects"], "viscous_friction"]))
    assert rules_run(snakemake(tree, "-n", DESIGN)) == {"excitation"}

    edit_yaml(model, lambda config: config.update(effects=[*config["effects"], "cogging"]))
    with pytest.raises(AssertionError, match=r"model\.yaml.*effects"):
        snakemake(tree, "-n", DESIGN)

    model.write_text(shipped)
    assert "Nothing to be done" in snakemake(tree, "-n", DESIGN)


def test_excitation_yaml_edits_rerun_only_the_designs_they_change(tmp_path: Path, built_tree: Path) -> None:
    """A design's jobs take its own entry of excitation.yaml (defaults merged) as a param: a comment or another
    design's entry reruns neither of its stages; a default it takes reruns both; a bad entry stops the run before
    any job, naming the file, the key and the fix."""
    tree, config, shipped = _built_copy_with_config(tmp_path, built_tree, "excitation.yaml")

    config.write_text(shipped + "# a comment changes no design\n")
    assert "Nothing to be done" in snakemake(tree, "-n", DESIGN)
    edit_yaml(config, lambda data: data["designs"].update(slow={"base_frequency_hz": 0.1, "duration_s": 10.0}))
    assert "Nothing to be done" in snakemake(tree, "-n", DESIGN)
    assert rules_run(snakemake(tree, "-n", "results/panda/excitation/slow.csv")) == {"excitation_start", "excitation"}

    edit_yaml(config, lambda data: data["defaults"]["margins"].update(collision_m=0.011))
    assert rules_run(snakemake(tree, "-n", DESIGN)) == {"excitation_start", "excitation"}

    edit_yaml(config, lambda data: data["designs"]["identification"].update(excite=["panda_joint9"]))
    with pytest.raises(AssertionError, match=r"excitation\.yaml: .*designs/identification/excite.*panda_joint9"):
        snakemake(tree, "-n", DESIGN)

    config.write_text(shipped)
    assert "Nothing to be done" in snakemake(tree, "-n", DESIGN)


def test_lab_yaml_edits_rerun_only_the_runs_of_the_scenarios_they_change(tmp_path: Path, built_tree: Path) -> None:
    """A lab run and its truth take their scenario's settings (defaults merged, description left out) as a param: a
    comment or a description reruns no run; an edit of one scenario reruns that scenario's runs and truth, never
    another scenario's; a default reruns every scenario that takes it."""
    tree = copy_built(built_tree, tmp_path / "project")
    lab = tree / "configs" / "panda" / "lab.yaml"
    shipped = lab.read_text()
    worn, demo = "results/panda/lab/real_arm_like_worn_2026_11", "results/panda/lab/real_arm_like"
    targets = [f"{scenario}/{run}.parquet" for scenario in (worn, demo) for run in ("fit", "holdout")]
    truths = [f"{worn}/truth.yaml", f"{demo}/truth.yaml"]
    assert "Nothing to be done" in snakemake(tree, "-n", *targets, *truths)

    edit_yaml(lab, lambda data: data["scenarios"][worn.split("/")[-1]].update(description="the demo arm, worn"))
    lab.write_text(lab.read_text() + "# a comment changes no scenario\n")
    assert "Nothing to be done" in snakemake(tree, "-n", *targets, *truths)

    edit_yaml(lab, lambda data: data["scenarios"][worn.split("/")[-1]]["sensors"].update(torque_noise_std=0.04))
    dry = snakemake(tree, "-n", *targets, *truths)
    assert rules_run(dry) == {"lab_run", "lab_truth"}, dry
    assert set(jobs_outputs(dry)) == {f"{worn}/{name}" for name in (
        "fit.parquet", "fit.yaml", "holdout.parquet", "holdout.yaml", "truth.yaml")}, "no other scenario's runs"

    lab.write_text(shipped)
    edit_yaml(lab, lambda data: data["defaults"].update(sample_rate_hz=500))
    assert {f"{worn}/fit.parquet", f"{demo}/fit.parquet"} <= set(jobs_outputs(snakemake(tree, "-n", *targets)))

    lab.write_text(shipped)
    assert "Nothing to be done" in snakemake(tree, "-n", *targets, *truths)

"""sim2real.workflow: the files and settings rules/common.smk hands to the jobs, on the shipped configs."""

from __future__ import annotations

import doctest
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

import sim2real.workflow
from sim2real.assets.robot_config import read_robot_config
from sim2real.errors import InputError
from sim2real.excitation.config import identification_effects
from sim2real.identification.model_config import load_model_config
from sim2real.measurements import load_measurement_list
from sim2real.measurements.campaigns import robot_campaigns
from sim2real.workflow import configs, of_wildcards, paths, targets

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def in_the_repository(monkeypatch: pytest.MonkeyPatch) -> None:
    """The workflow's paths are relative to the directory Snakemake runs in: the repository."""
    monkeypatch.chdir(REPO)


def test_an_input_function_passes_the_named_wildcards_in_order() -> None:
    assert doctest.testmod(sim2real.workflow).failed == 0
    job = SimpleNamespace(robot="panda", design="separate-rotor_inertia-vs-link_inertia", variant="")
    assert of_wildcards(paths.separation_ladder, "robot", "design")(job) == ["results/panda/sysid/ladder.json"]
    assert of_wildcards(paths.xacro_args, "robot", "variant")(job)["calibration"] == ""
    assert of_wildcards(paths.design_start, "robot", "design").__name__ == "design_start"


def test_the_jobs_take_robot_yaml_without_its_collision_section() -> None:
    settings = read_robot_config("configs/ur5/robot.yaml")
    assert "collision" in settings
    assert configs.robot_params("ur5") == {k: v for k, v in settings.items() if k != "collision"}
    assert configs.collision_section("ur5") == settings["collision"]
    assert configs.collision_tolerance("ur5") == settings["collision"].get("tolerance", {})
    assert configs.robot_xacro("panda") == settings_xacro("panda")


def settings_xacro(robot: str) -> str:
    return read_robot_config(f"configs/{robot}/robot.yaml").get("xacro", f"robots/{robot}/{robot}.urdf.xacro")


def test_the_xacro_includes_are_the_robots_and_the_common_ones() -> None:
    includes = configs.xacro_includes("panda")
    assert includes == sorted(includes) and configs.robot_xacro("panda") in includes
    assert {Path(p).parts[1] for p in includes} <= {"panda", "common"}
    assert any(p.startswith("robots/common/") for p in includes)


def test_the_calibrated_tree_reads_the_calibration_and_the_identified_params() -> None:
    assert paths.calibration("panda", "") == [] and paths.identified_params("panda", "") == []
    assert paths.calibration("panda", "calibrated/") == ["results/panda/sysid/calibration.yaml"]
    assert paths.xacro_args("panda", "calibrated/")["calibration"] == "results/panda/sysid/calibration.yaml"
    assert paths.identified_params("panda", "calibrated/") == ["results/panda/sysid/params.yaml"]
    assert paths.identified_params_if_any("iiwa14") == ["results/iiwa14/sysid/params.yaml"]


def test_a_robot_without_a_model_ladder_is_neither_fitted_nor_identified(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "configs/measured_only").mkdir(parents=True)
    (tmp_path / "configs/measured_only/measurements.yaml").write_text("runs: []\n")
    monkeypatch.chdir(tmp_path)
    assert not configs.is_fitted("measured_only") and not configs.is_identified("measured_only")
    assert configs.model_config("measured_only") is None
    assert paths.sysid_ladder("measured_only", "") == [] and paths.identified_params_if_any("measured_only") == []
    assert targets.campaign_sysid_targets("measured_only", []) == []
    assert "results/measured_only/calibrated/mjcf/measured_only.xml" not in targets.mjcf_targets("measured_only")


def test_a_campaign_reads_its_own_list_and_writes_under_its_own_folder() -> None:
    assert configs.campaign_measurements("panda", "") == "configs/panda/measurements.yaml"
    assert configs.campaign_measurements("panda", "panda-2026-11/") == "configs/panda/campaigns/panda-2026-11.yaml"
    assert paths.sysid_ladder("panda", "panda-2026-11/") == ["results/panda/panda-2026-11/sysid/ladder.json",
                                                             "results/panda/panda-2026-11/sysid/residuals.npz"]
    assert paths.sysid_fits("panda", "") == "results/panda/sysid/fits"
    assert paths.gap_kept("panda", "panda-2026-11/") == "results/panda/panda-2026-11/gap/kept"
    files = paths.measurement_files("panda", "")
    entries = load_measurement_list("configs/panda/measurements.yaml")
    assert files[0::2] == [e.path.as_posix() for e in entries]
    assert all(meta == run.removesuffix(".parquet") + ".yaml" for run, meta in zip(files[0::2], files[1::2]))


def test_a_lab_run_plays_its_designed_excitation_and_a_design_reads_its_settings() -> None:
    designs = configs.lab_excitation_designs("panda")
    (scenario, run), design = next(iter(designs.items()))
    assert paths.lab_run_excitation("panda", scenario, run) == [f"results/panda/excitation/{design}.csv"]
    assert paths.lab_run_excitation("panda", scenario, "no_such_run") == []
    assert set(configs.lab_scenario("panda", scenario)) == {"joints", "settings"}
    assert set(configs.excitation_design("panda", design)) == {"joints", "excite", "settings"}
    with pytest.raises(InputError, match="configs/panda/excitation.yaml"):
        configs.excitation_design("panda", "no_such_design")
    separating = configs.excitation_design("panda", "separate-rotor_inertia-vs-link_inertia")
    assert separating["joints"] == configs.excitation_design("panda", design)["joints"]
    effects = load_model_config("configs/panda/model.yaml").effects
    assert configs.design_model_effects("panda") == identification_effects(list(effects))
    assert paths.separation_ladder("panda", design) == []


def test_coacd_decomposes_the_visual_mesh_of_the_same_name_unless_told_otherwise() -> None:
    meshes = {"visual": {"link1": "package://panda/meshes/visual/link1.dae"},
              "collision": {"link1": "package://panda/meshes/collision/link1.stl",
                            "hand": "package://panda/meshes/collision/hand.stl"}}
    source = configs.coacd_settings("panda", "link1")["source"]
    expected = {"visual": "results/panda/meshes/visual/link1", "collision": "results/panda/meshes/collision/link1.stl"}
    assert paths.coacd_source("panda", "link1", meshes) == expected[source]
    assert paths.coacd_dirs("panda", meshes) == {"hand": "results/panda/collision/hand",
                                                 "link1": "results/panda/collision/link1"}
    assert paths.coacd_timings("panda", meshes) == ["results/panda/benchmarks/coacd/hand.json",
                                                    "results/panda/benchmarks/coacd/link1.json"]
    assert paths.collision_part_dirs("panda", meshes)["package://panda/meshes/collision/hand.stl"] == \
        "results/panda/collision/hand"
    assert paths.visual_mesh_dirs("panda", meshes) == ["results/panda/meshes/visual/link1"]
    if configs.coacd_settings("panda", "hand")["source"] == "visual":
        with pytest.raises(InputError, match=r"configs/panda/robot.yaml.*collision.overrides.hand.*source: collision"):
            paths.coacd_source("panda", "hand", meshes)


URDF = """<robot name="r"><link name="{link}"><visual><geometry><mesh filename="package://r/meshes/a.stl"/></geometry>
</visual><collision><geometry><mesh filename="package://r/meshes/b.stl"/></geometry></collision></link></robot>"""


def test_the_mesh_lists_are_read_again_when_the_urdf_changes(tmp_path: Path) -> None:
    urdf = tmp_path / "r.urdf"
    urdf.write_text(URDF.format(link="base"))
    assert paths.mesh_names(str(urdf)) == {"visual": {"a": "package://r/meshes/a.stl"},
                                           "collision": {"b": "package://r/meshes/b.stl"}}
    assert paths.mesh_links(str(urdf), "visual", "a") == ["base"]
    urdf.write_text(URDF.format(link="body").replace("a.stl", "c.stl"))
    os.utime(urdf, (urdf.stat().st_atime, urdf.stat().st_mtime + 10))
    assert paths.mesh_names(str(urdf))["visual"] == {"c": "package://r/meshes/c.stl"}
    assert paths.mesh_links(str(urdf), "collision", "b") == ["body"]


def test_the_targets_of_an_identified_robot_cover_every_stage_and_campaign() -> None:
    campaigns = robot_campaigns("panda")
    wanted = targets.robot_targets("panda", campaigns)
    assert len(wanted) == len(set(wanted))
    for path in ["results/panda/panda.urdf", "results/panda/calibrated/mjcf/panda.xml", "results/panda/mjcf/scene.xml",
                 "results/panda/collision/report.json", "results/panda/calibrated/equivalence.json",
                 "results/panda/sysid/ladder.json", "results/panda/panda-2026-11/sysid/calibration.yaml",
                 "results/panda/gap.md", "results/panda/panda-2026-11/gap.json", "results/panda/dr/summary.svg"]:
        assert path in wanted, path
    assert targets.excitation_targets("panda") and all(t.startswith("results/panda/excitation/")
                                                        for t in targets.excitation_targets("panda"))
    assert targets.excitation_targets("ur5") == []
    truths = targets.lab_truth_targets("panda", campaigns)
    assert truths and all(t.startswith("results/panda/lab/") and t.endswith("/truth.yaml") for t in truths)


def test_the_fleet_reads_every_campaign_of_every_fitted_robot() -> None:
    by_robot = {robot: robot_campaigns(robot) for robot in ("panda", "ur5")}
    records = targets.fleet_campaigns(by_robot)
    assert [(r["robot"], r["campaign"]) for r in records] == [
        (c.robot, c.name) for robot in ("panda", "ur5") for c in by_robot[robot]]
    other = next(r for r in records if r["campaign"] == "panda-2026-11")
    assert other["ladder"] == "results/panda/panda-2026-11/sysid/ladder.json"
    assert other["params"] == "results/panda/panda-2026-11/sysid/params.yaml"
    assert other["report"] == "results/panda/panda-2026-11/gap.md"

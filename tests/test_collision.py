"""CoACD convex decomposition: settings, determinism, fidelity measures, report, and the Snakemake wiring."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import mujoco
import pytest
import trimesh

from buildtree import edit_yaml, run_snakemake
from collision_usd_build import ROBOT, TARGETS
from sim2real.assets.collision import (
    CoacdSettings,
    MeshSettings,
    Tolerance,
    collision_report,
    decompose,
    flag_reasons,
    load_source_mesh,
    mesh_settings,
    part_files,
    shape_fidelity,
    write_timing,
)
from sim2real.errors import InputError
from sim2real.assets.urdf import resolve_package_uri

PANDA_MESHES = "package://example-robot-data/robots/panda_description/meshes"
FAST = MeshSettings(source="collision", coacd=CoacdSettings(threshold=0.3, max_convex_hull=4, preprocess_mode="off", mcts_iterations=10))


@pytest.fixture(scope="module")
def built(built_tree: Path) -> Path:
    """The suite's shared built tree (conftest): read-only."""
    return built_tree


def test_settings_merge_defaults_section_and_per_mesh_override() -> None:
    section = {"source": "visual", "coacd": {"threshold": 0.08, "seed": 3}, "overrides": {"hand": {"threshold": 0.2, "source": "collision"}}}
    hand = mesh_settings(section, "hand")
    link1 = mesh_settings(section, "link1")
    assert (hand.source, hand.coacd.threshold, hand.coacd.seed) == ("collision", 0.2, 3)
    assert (link1.source, link1.coacd.threshold, link1.coacd.max_convex_hull) == ("visual", 0.08, CoacdSettings().max_convex_hull)
    assert MeshSettings.from_params(hand.as_params()) == hand  # params round trip: what Snakemake compares
    coarse = mesh_settings({**section, "voxels_per_extent": 30}, "hand")
    assert (coarse.voxels_per_extent, hand.voxels_per_extent) == (30, 80)  # the measures' solid, section-wide
    assert MeshSettings.from_params(coarse.as_params()) == coarse and coarse.as_params() != hand.as_params()


def test_unknown_setting_names_the_mesh_and_the_key() -> None:
    with pytest.raises(InputError, match=r"mesh 'hand'.*treshold"):
        mesh_settings({"overrides": {"hand": {"treshold": 0.1}}}, "hand", "configs/panda/robot.yaml")
    with pytest.raises(InputError, match="source"):
        mesh_settings({"source": "cad"}, "link1")


def test_decomposition_is_byte_identical_and_complete(tmp_path: Path) -> None:
    source = resolve_package_uri(f"{PANDA_MESHES}/collision/link4.stl")
    first = decompose(source, FAST, tmp_path / "a" / "link4")
    second = decompose(source, FAST, tmp_path / "b" / "link4")
    files_a = sorted(p.name for p in first.parts_dir.iterdir())
    assert files_a == sorted(p.name for p in second.parts_dir.iterdir())
    for name in files_a:
        assert (first.parts_dir / name).read_bytes() == (second.parts_dir / name).read_bytes(), name
    manifest = json.loads((first.parts_dir / "parts.json").read_text())
    assert manifest["settings"] == FAST.as_params()
    assert part_files(first.parts_dir) == first.part_files
    for file in first.part_files:  # every part is a closed convex hull
        part = trimesh.load(file)
        assert part.is_watertight and part.is_convex
    assert "seconds" not in json.dumps(manifest)  # wall time never enters the byte-compared output


def test_concave_visual_mesh_gives_several_parts_that_follow_the_shape(repo_root: Path, tmp_path: Path) -> None:
    source = resolve_package_uri(f"{PANDA_MESHES}/visual/hand.dae")
    settings = MeshSettings("visual", CoacdSettings(threshold=0.2, max_convex_hull=4, mcts_iterations=10, mcts_nodes=10, resolution=500))
    result = decompose(source, settings, tmp_path / "hand")
    assert len(result.part_files) > 1
    single_hull = shape_fidelity(load_source_mesh(source), [load_source_mesh(source).convex_hull])
    # on average, several parts fill less of the hand's concavity than its one convex hull does
    assert result.fidelity["mean_mm"] < single_hull["mean_mm"]
    assert result.fidelity["source_to_parts_max_mm"] < 2.0  # the parts cover the source surface


def test_fidelity_measures_are_zero_for_the_shape_itself_and_flag_a_shrunken_part() -> None:
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    exact = shape_fidelity(box, [box])
    assert exact["hausdorff_mm"] < 1e-6 and exact["volume_ratio"] == pytest.approx(1.0)
    assert flag_reasons(exact, Tolerance()) == []
    small = trimesh.creation.box((0.1, 0.1, 0.06))  # misses 20 mm on both z faces
    missed = shape_fidelity(box, [small])
    assert missed["source_to_parts_max_mm"] == pytest.approx(20.0, abs=0.5)
    reasons = flag_reasons(missed, Tolerance(hausdorff_mm=10.0))
    assert any("Hausdorff" in r for r in reasons) and any("volume ratio" in r for r in reasons)


def test_report_is_deterministic_and_keeps_times_in_the_table_only(tmp_path: Path) -> None:
    source = resolve_package_uri(f"{PANDA_MESHES}/collision/link7.stl")
    decomposition = decompose(source, FAST, tmp_path / "link7")
    write_timing(tmp_path / "t1.json", "link7", 1.5)
    write_timing(tmp_path / "t2.json", "link7", 9.5)
    strict = Tolerance(hausdorff_mm=1e-6)
    report = collision_report({"link7": decomposition.parts_dir}, {"link7": tmp_path / "t1.json"}, strict, tmp_path / "r1.json", tmp_path / "s1.tsv")
    collision_report({"link7": decomposition.parts_dir}, {"link7": tmp_path / "t2.json"}, strict, tmp_path / "r2.json", tmp_path / "s2.tsv")
    assert (tmp_path / "r1.json").read_bytes() == (tmp_path / "r2.json").read_bytes()
    assert report["flagged"] == ["link7"] and report["meshes"]["link7"]["flag_reasons"]
    table = (tmp_path / "s1.tsv").read_text().splitlines()
    assert table[0].split("\t")[:3] == ["mesh", "source", "hulls"] and "1.50" in table[1]


def test_missing_source_mesh_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        decompose(tmp_path / "nope.stl", FAST, tmp_path / "out")
    assert not (tmp_path / "out").exists()  # no partial output


def test_workflow_builds_parts_report_and_mjcf_uses_them(built: Path) -> None:
    results = built / "results" / ROBOT
    report = json.loads((results / "collision" / "report.json").read_text())
    assert set(report["meshes"]) == {"hand", "link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7"}
    assert report["meshes"]["hand"]["hulls"] > 1
    model = mujoco.MjModel.from_xml_path(str(results / "mjcf" / "scene.xml"))
    hand = model.body("panda_hand").id
    collision_geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == hand and model.geom_group[g] == 3]
    assert len(collision_geoms) == report["meshes"]["hand"]["hulls"]
    xml = (results / "mjcf" / f"{ROBOT}.xml").read_text()
    assert re.search(r'file="\.\./collision/hand/part_01\.stl"', xml)


def coacd_jobs(log: str) -> list[str]:
    """Mesh names of the coacd jobs a Snakemake (dry-run) log lists."""
    names = []
    for block in re.split(r"\n\s*\n", log):
        if re.search(r"^\s*(?:checkpoint|rule) coacd:", block, flags=re.MULTILINE):
            names += re.findall(r"wildcards: robot=\w+, name=(\w+)", block)
    return sorted(set(names))


def test_settings_change_reruns_only_that_mesh(built: Path, tmp_path: Path) -> None:
    tree = tmp_path / "project"
    shutil.copytree(built, tree, symlinks=True)  # keeps mtimes and .snakemake metadata

    def stricter_link3(data: dict) -> None:
        data["collision"].setdefault("overrides", {})["link3"] = {"threshold": 0.25}

    assert "Nothing to be done" in run_snakemake(tree, "-n", *TARGETS)
    edit_yaml(tree / "configs" / ROBOT / "robot.yaml", stricter_link3)
    assert coacd_jobs(run_snakemake(tree, "-n", *TARGETS)) == ["link3"]

"""Two arms of a fleet, two campaigns each, through the DAG (issue 12, "Done when").

The Panda's virtual lab has an arm whose joint-4 Coulomb friction rises between two campaigns
(scenarios fleet_drift_2026_10/_11) and an arm measured twice with the same physics
(fleet_steady_2026_10/_11, new excitation and sensor noise). Campaign files point at those runs; the
drifting arm's first campaign is the default one (configs/panda/measurements.yaml, reports at the old
paths). The fleet view must name the drifted parameter and claim nothing for the unchanged arm.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from buildtree import edit_yaml, rules_run, run_snakemake
from readme import copy_built

pytestmark = pytest.mark.slow


def _built_copy(built_tree: Path, dest: Path) -> Path:
    """The suite's shared tree (assets built at fast settings) with the shipped lab runs and fit settings back:
    its short lab runs and few bootstrap replicates cannot resolve a drift."""
    return copy_built(built_tree, dest, shipped=("configs/panda/lab.yaml", "configs/panda/model.yaml"))


def _campaign(scenario: str, arm: str, date: str) -> str:
    return yaml.safe_dump({
        "runs": [{"name": role, "path": f"results/panda/lab/{scenario}/{role}.parquet", "role": role}
                 for role in ("fit", "holdout")],
        "campaign": {"arm": arm, "date": date},
    }, sort_keys=False)


def test_drifted_arm_is_named_unchanged_arm_is_not(tmp_path: Path, built_tree: Path) -> None:
    tree = _built_copy(built_tree, tmp_path / "repo")
    edit_yaml(tree / "configs/config.yaml", lambda c: c.update(robots=["panda"]))
    edit_yaml(tree / "configs/panda/model.yaml", lambda m: m.update(effects=["coulomb_friction"]))

    def short_runs(lab: dict) -> None:  # fast settings: 8 s per run instead of 12
        for name, scenario in lab["scenarios"].items():
            if name.startswith("fleet_"):
                scenario["duration_s"] = 8
    edit_yaml(tree / "configs/panda/lab.yaml", short_runs)
    (tree / "configs/panda/measurements.yaml").write_text(_campaign("fleet_drift_2026_10", "panda_2", "2026-10"))
    campaigns = tree / "configs/panda/campaigns"
    for shipped in campaigns.glob("*.yaml"):  # the shipped demo's second campaign: this test brings its own
        shipped.unlink()
    (campaigns / "panda_2-2026-11.yaml").write_text(_campaign("fleet_drift_2026_11", "panda_2", "2026-11"))
    (campaigns / "panda_3-2026-10.yaml").write_text(_campaign("fleet_steady_2026_10", "panda_3", "2026-10"))
    (campaigns / "panda_3-2026-11.yaml").write_text(_campaign("fleet_steady_2026_11", "panda_3", "2026-11"))

    log = run_snakemake(tree, "results/fleet.md", "results/panda/gap.json", "results/panda/panda_2-2026-11/gap.json")
    assert "fleet" in rules_run(log)
    # two campaigns of the same arm, two reports: the default one at the old path, the next in its directory
    reports = [json.loads((tree / p).read_text()) for p in ("results/panda/gap.json",
                                                            "results/panda/panda_2-2026-11/gap.json")]
    assert [r["runs"][0]["path"] for r in reports] == ["results/panda/lab/fleet_drift_2026_10/fit.parquet",
                                                      "results/panda/lab/fleet_drift_2026_11/fit.parquet"]
    assert (tree / "results/panda/panda_2-2026-11/gap.md").exists()

    fleet = json.loads((tree / "results/fleet.json").read_text())
    arms = {a["arm"]: a for a in fleet["arms"]}
    assert set(arms) == {"panda_2", "panda_3"}
    assert [c["campaign"] for c in arms["panda_2"]["campaigns"]] == ["default", "panda_2-2026-11"]

    (change,) = arms["panda_2"]["changes"]
    assert (change["effect"], change["parameter"], change["joint"], change["direction"]) == (
        "coulomb_friction", "friction", "panda_joint4", "rose")
    assert change["before"]["value"] == pytest.approx(0.6, abs=0.05)
    assert change["after"]["value"] == pytest.approx(0.85, abs=0.05)
    assert change["text"].startswith("panda_2: coulomb_friction on panda_joint4 rose from ")
    assert change["text"].endswith(" N·m between 2026-10 and 2026-11")

    assert arms["panda_3"]["changes"] == []
    assert arms["panda_3"]["comparisons"][0]["values_compared"] == 7
    assert fleet["summary"]["drifted_arms"] == ["panda_2"]

    md = (tree / "results/fleet.md").read_text()
    assert change["text"] in md
    assert "panda_3: no identified value changed between 2026-10 and 2026-11" in md
    assert (tree / "results/fleet/parameters.png").stat().st_size > 10_000


def test_shipped_demo_names_the_worn_joint(tmp_path: Path, built_tree: Path) -> None:
    """The fleet demo as shipped (issue 21): the default campaign's Panda measured again with a worn
    joint 4 (configs/panda/campaigns/panda-2026-11.yaml, lab scenario real_arm_like_worn_2026_11).
    Lab runs, fits and bootstrap at the shipped settings; fast CoACD (no effect on the dynamics)."""
    tree = _built_copy(built_tree, tmp_path / "repo")
    edit_yaml(tree / "configs/config.yaml", lambda c: c.update(robots=["panda"]))
    run_snakemake(tree, "results/fleet.md")
    fleet = json.loads((tree / "results/fleet.json").read_text())
    (arm,) = fleet["arms"]
    assert (arm["arm"], [c["date"] for c in arm["campaigns"]]) == ("panda", ["2026-10", "2026-11"])
    (change,) = arm["changes"]  # the worn joint, and nothing else
    assert (change["effect"], change["joint"], change["direction"]) == ("asymmetric_friction", "panda_joint4", "rose")
    assert change["parameter"] == "amplitude"
    assert change["before"]["value"] == pytest.approx(1.28, abs=0.05)
    assert change["after"]["value"] == pytest.approx(1.727, abs=0.05)
    md = (tree / "results/fleet.md").read_text()
    assert change["text"] in md and md.count("rose from") + md.count("fell from") == 1

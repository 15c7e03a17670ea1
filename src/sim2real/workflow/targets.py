"""Every stage's final outputs for one robot, which ``snakemake all`` builds (``all_targets`` in rules/common.smk),
and the campaigns the fleet view reads."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

from sim2real.files import read_yaml
from sim2real.measurements import load_measurement_list
from sim2real.measurements.campaigns import Campaign
from sim2real.workflow import configs
from sim2real.workflow.paths import nominal_urdf


def urdf_targets(robot: str) -> list[str]:
    return [nominal_urdf(robot)]


def mjcf_targets(robot: str) -> list[str]:
    """The MJCF and its scene, nominal and (where the robot is identified) calibrated."""
    return [f"results/{robot}/{variant}mjcf/{robot}.xml" for variant in ("", "calibrated/")
            if not variant or configs.is_identified(robot)] + [f"results/{robot}/mjcf/scene.xml"]


def collision_targets(robot: str) -> list[str]:
    return [f"results/{robot}/collision/report.json"]


def usd_targets(robot: str) -> list[str]:
    """The USD and its equivalence check with the URDF and the MJCF, nominal and (identified) calibrated."""
    return [f"results/{robot}/{variant}{name}" for variant in ("", "calibrated/")
            if not variant or configs.is_identified(robot)
            for name in (f"usd/{robot}.usda", "equivalence.json")]


def dr_targets(robot: str) -> list[str]:
    return [f"results/{robot}/dr.json", f"results/{robot}/dr/coverage.json", f"results/{robot}/dr/summary.svg"]


def excitation_targets(robot: str) -> list[str]:
    """Every design of configs/{robot}/excitation.yaml (the file is validated by the rule itself)."""
    path = configs.excitation_config(robot)
    if not os.path.exists(path):
        return []
    designs = sorted((read_yaml(path) or {}).get("designs") or {})
    return [f"results/{robot}/excitation/{name}.csv" for name in designs] + [
        f"results/{robot}/excitation/{name}.md" for name in designs]


def lab_truth_targets(robot: str, campaigns: Sequence[Campaign]) -> list[str]:
    """truth.yaml of every lab scenario the robot's campaigns measure (no comparing rule reads it)."""
    prefix = f"results/{robot}/lab/"
    scenarios = {entry.path.as_posix()[len(prefix):].split("/")[0]
                 for campaign in campaigns for entry in load_measurement_list(campaign.measurements)
                 if entry.path.as_posix().startswith(prefix)}
    return [f"{prefix}{scenario}/truth.yaml" for scenario in sorted(scenarios)]


def campaign_sysid_targets(robot: str, campaigns: Sequence[Campaign]) -> list[str]:
    """The fitted ladder and calibration of every campaign, where the robot has a model ladder."""
    if not configs.is_fitted(robot):
        return []
    return [f"results/{robot}/{c.prefix}sysid/{name}" for c in campaigns for name in ("ladder.json", "calibration.yaml")]


def campaign_report_targets(robot: str, campaigns: Sequence[Campaign]) -> list[str]:
    """gap.json and gap.md of every campaign of the robot."""
    return [f"results/{robot}/{c.prefix}{name}" for c in campaigns for name in ("gap.json", "gap.md")]


def fleet_campaigns(campaigns: Mapping[str, Sequence[Campaign]]) -> list[dict[str, Any]]:
    """Every identified campaign of every robot ({robot: its campaigns}), with the files the fleet view reads."""
    return [{"robot": c.robot, "campaign": c.name, "arm": c.arm, "date": c.date, "measurements": c.measurements,
             "report": f"{c.results}gap.md", "ladder": f"{c.results}sysid/ladder.json",
             "params": f"{c.results}sysid/params.yaml"}
            for robot, robot_campaigns in campaigns.items() if configs.is_fitted(robot) for c in robot_campaigns]


def robot_targets(robot: str, campaigns: Sequence[Campaign]) -> list[str]:
    """Every final output of one robot ``snakemake all`` builds, stage by stage; ``campaigns``: the robot's
    (:func:`sim2real.measurements.campaigns.robot_campaigns`)."""
    return [*urdf_targets(robot), *mjcf_targets(robot), *collision_targets(robot), *usd_targets(robot),
            *lab_truth_targets(robot, campaigns), *campaign_sysid_targets(robot, campaigns),
            *campaign_report_targets(robot, campaigns), *dr_targets(robot), *excitation_targets(robot)]

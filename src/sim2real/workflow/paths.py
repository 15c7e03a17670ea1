"""The built files a job reads, given its wildcards: results/{robot}/... paths (relative to the workflow's directory).

``variant`` is "" for the nominal tree and "calibrated/" for the calibrated one; ``campaign`` is "" for the default
campaign and "<name>/" for another (:mod:`sim2real.measurements.campaigns`).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from typing import Any

from sim2real.assets import meshes as asset_meshes
from sim2real.assets import urdf as asset_urdf
from sim2real.errors import InputError
from sim2real.excitation import names as design_names
from sim2real.measurements import load_measurement_list
from sim2real.workflow import configs

# What a robot's nominal URDF lists: {kind: {mesh name: package uri}} (sim2real.assets.urdf.mesh_names).
MeshNames = Mapping[str, Mapping[str, str]]


def nominal_urdf(robot: str) -> str:
    return f"results/{robot}/{robot}.urdf"


def calibration(robot: str, variant: str) -> list[str]:
    """The calibration the calibrated tree's Xacro reads (none for the nominal tree)."""
    return [f"results/{robot}/sysid/calibration.yaml"] if variant else []


def xacro_args(robot: str, variant: str) -> dict[str, Any]:
    """robot.yaml's ``xacro_args`` and ``calibration:=`` the calibration file ("" for the nominal tree)."""
    args = dict(configs.robot_settings(robot).get("xacro_args") or {})
    args["calibration"] = calibration(robot, variant)[0] if variant else ""
    return args


def identified_params(robot: str, variant: str) -> list[str]:
    """The calibrated MJCF also takes what the URDF cannot hold (armature, delay, gear) from sysid."""
    return [f"results/{robot}/sysid/params.yaml"] if variant else []


def identified_params_if_any(robot: str) -> list[str]:
    """sysid/params.yaml where the robot is identified (randomization coverage), else nothing."""
    return [f"results/{robot}/sysid/params.yaml"] if configs.is_identified(robot) else []


def sysid_ladder(robot: str, campaign: str) -> list[str]:
    """The campaign's ladder (with the diagnosis the gap report words) and the last rung's residuals, where the robot
    has a model ladder."""
    if not configs.is_fitted(robot):
        return []
    return [f"results/{robot}/{campaign}sysid/ladder.json", f"results/{robot}/{campaign}sysid/residuals.npz"]


def sysid_fits(robot: str, campaign: str) -> str:
    """Where a campaign's sysid keeps its rungs and diagnoses for the next round (sim2real.cache.FitCache)."""
    return f"results/{robot}/{campaign}sysid/fits"


def gap_kept(robot: str, campaign: str) -> str:
    """Where a campaign's gap report keeps its replays and figures for the next round."""
    return f"results/{robot}/{campaign}gap/kept"


def measurement_files(robot: str, campaign: str) -> list[str]:
    """Every run table of the campaign's measurement list and its metadata YAML (so lab runs get built)."""
    files = []
    for entry in load_measurement_list(configs.campaign_measurements(robot, campaign)):
        files += [entry.path.as_posix(), entry.path.with_suffix(".yaml").as_posix()]
    return files


def lab_run_excitation(robot: str, scenario: str, run: str) -> list[str]:
    """The designed excitation a lab run plays (lab.yaml ``runs: [{..., excitation: <design>}]``), if any."""
    design = configs.lab_excitation_designs(robot).get((scenario, run))
    return [f"results/{robot}/excitation/{design}.csv"] if design else []


def design_start(robot: str, design: str) -> list[str]:
    """Where a design starts: its design for friction alone (rule excitation_start)."""
    return [f"results/{robot}/excitation/{design}.start.npz"]


def separation_ladder(robot: str, design: str) -> list[str]:
    """The diagnosis a separating design (separate-<a>-vs-<b>) reads its two fitted candidates from."""
    if design_names.confounded_pair(design) is None:
        return []
    return [f"results/{robot}/sysid/ladder.json"]


def mesh_names(urdf: str) -> MeshNames:
    """{kind: {name: package uri}} of a built URDF, read once per version of the file."""
    return _mesh_names(urdf, os.path.getmtime(urdf))


@functools.cache
def _mesh_names(urdf: str, modified: float) -> MeshNames:
    return asset_urdf.mesh_names(urdf)


def mesh_links(urdf: str, kind: str, name: str) -> list[str]:
    """The links of a built URDF that use the ``kind`` mesh ``name`` (named by a mesh job's error)."""
    return _mesh_links(urdf, os.path.getmtime(urdf))[kind][name]


@functools.cache
def _mesh_links(urdf: str, modified: float) -> dict[str, dict[str, list[str]]]:
    return asset_meshes.mesh_links(urdf)


def mesh_source(meshes: MeshNames, kind: str, name: str) -> str:
    """The source file of a mesh, its package URI resolved."""
    return str(asset_urdf.resolve_package_uri(meshes[kind][name]))


def visual_mesh_dirs(robot: str, meshes: MeshNames) -> list[str]:
    return [f"results/{robot}/meshes/visual/{name}" for name in sorted(meshes["visual"])]


def coacd_dirs(robot: str, meshes: MeshNames) -> dict[str, str]:
    """{collision mesh name: its convex parts directory} of every URDF collision mesh."""
    return {name: f"results/{robot}/collision/{name}" for name in sorted(meshes["collision"])}


def coacd_timings(robot: str, meshes: MeshNames) -> list[str]:
    """The wall-time record of every collision mesh's CoACD job (the collision report's table)."""
    return [f"results/{robot}/benchmarks/coacd/{name}.json" for name in sorted(meshes["collision"])]


def collision_part_dirs(robot: str, meshes: MeshNames) -> dict[str, str]:
    """{URDF collision mesh URI: its CoACD parts directory}: the collision geoms of the MJCF and the USD."""
    return {uri: f"results/{robot}/collision/{name}" for name, uri in sorted(meshes["collision"].items())}


def coacd_source(robot: str, name: str, meshes: MeshNames) -> str:
    """The mesh CoACD decomposes: the detailed visual mesh of the same name or the coarse collision STL."""
    if configs.coacd_settings(robot, name)["source"] == "collision":
        return f"results/{robot}/meshes/collision/{name}.stl"
    if name not in meshes["visual"]:
        raise InputError(configs.robot_config(robot), f"collision.overrides.{name}",
                         f"no visual mesh named '{name}' to decompose", "set 'source: collision' for this mesh")
    return f"results/{robot}/meshes/visual/{name}"

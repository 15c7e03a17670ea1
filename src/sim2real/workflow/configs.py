"""A robot's config files under ``configs/{robot}/`` and ``robots/{robot}/``, and what of them each job takes.

A job takes the part of a config it reads as a param rather than the file as an input: it reruns when that part
changes, not after an edit of a comment or of another part. Each config is read once per process.
"""

from __future__ import annotations

import functools
import glob
import os
from typing import Any

from sim2real.assets import collision as asset_collision
from sim2real.assets import robot_config as asset_robot_config
from sim2real.excitation import config as excitation_settings
from sim2real.excitation import names as design_names
from sim2real.identification import model_config as identification_model_config
from sim2real.identification.model_config import ModelConfig
from sim2real import lab
from sim2real.measurements import bags, campaigns


def robot_dir(robot: str) -> str:
    return f"robots/{robot}"


def robot_config(robot: str) -> str:
    return f"configs/{robot}/robot.yaml"


def measurement_list(robot: str) -> str:
    return f"configs/{robot}/measurements.yaml"


def model_ladder(robot: str) -> str:
    return f"configs/{robot}/model.yaml"


def lab_config(robot: str) -> str:
    return f"configs/{robot}/lab.yaml"


def excitation_config(robot: str) -> str:
    return f"configs/{robot}/excitation.yaml"


@functools.cache
def robot_settings(robot: str) -> dict[str, Any]:
    """configs/{robot}/robot.yaml as a dict, validated against schemas/robot.schema.yaml."""
    return asset_robot_config.read_robot_config(robot_config(robot))


def robot_params(robot: str) -> dict[str, Any]:
    """What the MJCF, USD, sysid and excitation jobs read of robot.yaml: all but ``collision`` (the CoACD jobs and
    the collision report take that section as their own params; new parts rerun the MJCF through them)."""
    return {key: value for key, value in robot_settings(robot).items() if key != "collision"}


def robot_xacro(robot: str) -> str:
    return robot_settings(robot).get("xacro", f"{robot_dir(robot)}/{robot}.urdf.xacro")


def xacro_includes(robot: str) -> list[str]:
    """Every Xacro file the robot's Xacro may include (its own folder and robots/common), sorted."""
    files = set(glob.glob(f"{robot_dir(robot)}/**/*.xacro", recursive=True))
    files |= set(glob.glob("robots/common/**/*.xacro", recursive=True))
    return sorted(files)


def collision_section(robot: str) -> dict[str, Any]:
    """robot.yaml's ``collision`` section ({} without one)."""
    return robot_settings(robot).get("collision") or {}


def collision_tolerance(robot: str) -> dict[str, Any]:
    """What the collision report checks the CoACD parts against (robot.yaml's ``collision.tolerance``, {} without)."""
    return collision_section(robot).get("tolerance") or {}


def coacd_settings(robot: str, mesh: str) -> dict[str, Any]:
    """Settings of one collision mesh (defaults < collision.coacd < collision.overrides.<mesh>) as plain params."""
    return asset_collision.mesh_settings(collision_section(robot), mesh, robot_config(robot)).as_params()


@functools.cache
def is_fitted(robot: str) -> bool:
    """Whether the robot has a model ladder (configs/{robot}/model.yaml): then its runs are fitted."""
    return os.path.exists(model_ladder(robot))


def is_identified(robot: str) -> bool:
    """Robots with measurements and a model ladder get identified parameters and calibrated assets."""
    return os.path.exists(measurement_list(robot)) and is_fitted(robot)


@functools.cache
def model_config(robot: str) -> ModelConfig | None:
    """configs/{robot}/model.yaml parsed and validated, None without one."""
    if not is_fitted(robot):
        return None
    return identification_model_config.load_model_config(model_ladder(robot))


def design_model_effects(robot: str) -> list[str]:
    """What an excitation design reads of model.yaml, the effects whose columns it makes identifiable: a comment, a
    fit setting or an effect that adds no column (link_inertia, payload, actuation_delay, sensor_delay) reruns no
    design; another effect added, removed or moved does."""
    ladder = model_config(robot)
    return excitation_settings.identification_effects(list(ladder.effects) if ladder is not None else [])


@functools.cache
def excitation_design(robot: str, design: str) -> dict[str, Any]:
    """What a design's jobs read of excitation.yaml: the design's own entry with the defaults merged and checked (an
    error names the file, the key and the fix). A separating design takes the file's defaults."""
    separating = design_names.confounded_pair(design) is not None
    return excitation_settings.load_design(excitation_config(robot), design, allow_default=separating).spec()


@functools.cache
def lab_scenario(robot: str, scenario: str) -> dict[str, Any]:
    """What a lab run or truth reads of lab.yaml: its scenario's settings with the defaults, and the lab's joints (an
    error names the file, the key and the fix); a comment or another scenario's edit reruns none of its runs."""
    return lab.lab_scenario(lab_config(robot), scenario)


@functools.cache
def lab_excitation_designs(robot: str) -> dict[tuple[str, str], str]:
    """{(scenario, run): design} of configs/{robot}/lab.yaml."""
    return lab.excitation_designs(lab_config(robot))


def campaign_measurements(robot: str, campaign: str) -> str:
    """The measurement list of a ``{campaign}`` wildcard value ("" = configs/{robot}/measurements.yaml)."""
    return campaigns.campaign_file(robot, campaigns.campaign_name(campaign))


def bag_topics(robot: str) -> dict[str, str | None]:
    """ROS 2 topics of configs/{robot}/measurements.yaml (``ros2:``), with the package defaults."""
    return bags.ros2_topics(measurement_list(robot))

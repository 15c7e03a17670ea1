# Helpers shared by the rules files. Logic lives in src/sim2real; this only maps
# config and wildcards onto paths.
import os


ROBOTS = list(config["robots"])


wildcard_constraints:
    robot="|".join(ROBOTS) if ROBOTS else "[^/]+",


def robot_dir(robot):
    return f"robots/{robot}"


def robot_config(robot):
    return f"configs/{robot}/robot.yaml"


def has_measurements(robot):
    """Robots with measurements get the gap report, identified parameters and calibrated assets."""
    return os.path.exists(f"configs/{robot}/measurements.yaml")


def all_targets():
    """Every output `snakemake all` builds, stage by stage, for every configured robot."""
    targets = []
    for robot in ROBOTS:
        for stage_targets in STAGE_TARGETS:
            targets.extend(stage_targets(robot))
    return targets


# Each rules file appends a function robot -> list of its final outputs.
STAGE_TARGETS = []

# What the rules share: the config validated, the wildcards' patterns, the workflow's targets, the input functions
# (get_*) and the scheduling. Where files are and what of a config a job reads is sim2real.workflow's.
import os

from snakemake.utils import validate

import sim2real.measurements.campaigns as _campaigns
from sim2real.workflow import of_wildcards
from sim2real.workflow import configs as _configs
from sim2real.workflow import paths as _paths
from sim2real.workflow.configs import excitation_config, lab_config, model_ladder
from sim2real.workflow.configs import robot_config
from sim2real.workflow.targets import dr_targets, excitation_targets, fleet_campaigns
from sim2real.workflow.targets import robot_targets

validate(config, "../schemas/config.schema.yaml")

ROBOTS = list(config["robots"])
# Measurement campaigns per robot: configs/{robot}/measurements.yaml is the default one (reports under
# results/{robot}/), each configs/{robot}/campaigns/<name>.yaml another (reports under results/{robot}/<name>/).
CAMPAIGNS = {robot: _campaigns.robot_campaigns(robot) for robot in ROBOTS}


# Every global wildcard constraint lives here, before any rule: a `wildcard_constraints:` block in a
# later file re-applies constraints to the rules defined so far, which under a default storage
# provider (profiles/kubernetes) loses them on the urdf checkpoint's output.
wildcard_constraints:
    robot="|".join(ROBOTS) if ROBOTS else "[^/]+",
    variant="(calibrated/)?",
    scenario="[A-Za-z0-9_-]+",
    run="(?!truth$)[A-Za-z0-9_-]+",
    bag="[A-Za-z0-9_.-]+",
    design="[A-Za-z0-9_-]+",
    campaign=_campaigns.wildcard_pattern(
        [c.name for cs in CAMPAIGNS.values() for c in cs if c.prefix]
    ),


def all_targets():
    """Every output `snakemake all` builds: every configured robot's, stage by stage, then the fleet view."""
    targets = []
    for robot in ROBOTS:
        targets.extend(robot_targets(robot, CAMPAIGNS[robot]))
    return targets + ["results/fleet.json", "results/fleet.md"]


# ---- input functions: a job's wildcards mapped onto the files and settings it reads ----

get_robot_params = of_wildcards(_configs.robot_params, "robot")
get_xacro = of_wildcards(_configs.robot_xacro, "robot")
get_xacro_includes = of_wildcards(_configs.xacro_includes, "robot")
get_xacro_args = of_wildcards(_paths.xacro_args, "robot", "variant")
get_calibration = of_wildcards(_paths.calibration, "robot", "variant")
get_identified_params = of_wildcards(_paths.identified_params, "robot", "variant")
get_coacd_settings = of_wildcards(_configs.coacd_settings, "robot", "name")
get_collision_tolerance = of_wildcards(_configs.collision_tolerance, "robot")
get_lab_scenario = of_wildcards(_configs.lab_scenario, "robot", "scenario")
get_lab_run_excitation = of_wildcards(
    _paths.lab_run_excitation, "robot", "scenario", "run"
)
get_bag_topics = of_wildcards(_configs.bag_topics, "robot")
get_measurement_list = of_wildcards(_configs.campaign_measurements, "robot", "campaign")
get_measurement_files = of_wildcards(_paths.measurement_files, "robot", "campaign")
get_sysid_ladder = of_wildcards(_paths.sysid_ladder, "robot", "campaign")
get_sysid_fits = of_wildcards(_paths.sysid_fits, "robot", "campaign")
get_gap_kept = of_wildcards(_paths.gap_kept, "robot", "campaign")
get_identified_params_if_any = of_wildcards(_paths.identified_params_if_any, "robot")
get_design = of_wildcards(_configs.excitation_design, "robot", "design")
get_design_start = of_wildcards(_paths.design_start, "robot", "design")
get_separation_ladder = of_wildcards(_paths.separation_ladder, "robot", "design")
get_design_model_effects = of_wildcards(_configs.design_model_effects, "robot")


# ---- meshes: their list comes from the nominal URDF through the urdf checkpoint ----


def checkpoint_urdf(robot):
    """The robot's nominal URDF, once the urdf checkpoint built it: a mesh job's inputs and params come from it."""
    return checkpoints.urdf.get(robot=robot, variant="").output[0]


def robot_meshes(robot):
    """{kind: {name: package uri}} of the robot's nominal URDF."""
    return _paths.mesh_names(checkpoint_urdf(robot))


def get_mesh_uri(kind):
    return lambda w: robot_meshes(w.robot)[kind][w.name]


def get_mesh_source(kind):
    return lambda w: _paths.mesh_source(robot_meshes(w.robot), kind, w.name)


def get_mesh_links(kind):
    """The links that use the {name} mesh of ``kind`` (named by a mesh job's error)."""
    return lambda w: _paths.mesh_links(checkpoint_urdf(w.robot), kind, w.name)


def get_visual_mesh_dirs(wildcards):
    return _paths.visual_mesh_dirs(wildcards.robot, robot_meshes(wildcards.robot))


def get_collision_part_dirs(wildcards):
    return _paths.collision_part_dirs(wildcards.robot, robot_meshes(wildcards.robot))


def get_collision_parts(wildcards):
    return sorted(get_collision_part_dirs(wildcards).values())


def get_coacd_parts(wildcards):
    return list(
        _paths.coacd_dirs(wildcards.robot, robot_meshes(wildcards.robot)).values()
    )


def get_coacd_names(wildcards):
    return list(_paths.coacd_dirs(wildcards.robot, robot_meshes(wildcards.robot)))


def get_coacd_timings(wildcards):
    return _paths.coacd_timings(wildcards.robot, robot_meshes(wildcards.robot))


def get_coacd_source(wildcards):
    meshes = robot_meshes(
        wildcards.robot
    )  # the checkpoint get_coacd_parts asked for already
    return _paths.coacd_source(wildcards.robot, wildcards.name, meshes)


# ---- the fleet view: every identified campaign of every robot ----
FLEET_CAMPAIGNS = fleet_campaigns(CAMPAIGNS)


def get_fleet_records(wildcards):
    return FLEET_CAMPAIGNS


def get_fleet_ladders(wildcards):
    return [c["ladder"] for c in FLEET_CAMPAIGNS]


def get_fleet_params(wildcards):
    return [c["params"] for c in FLEET_CAMPAIGNS]


# ---- scheduling -------------------------------------------------------------------
# Of the jobs ready to run, Snakemake starts those of highest priority first, and a rule's priority does not pass to
# the jobs it waits for. Every robot's mesh conversions and CoACD jobs go first (MESH_PRIORITY): they are most of a
# cold build's work, and a long CoACD job (the UR5's wrist, 60-75 s) left for the end runs alone on one core while
# nothing else is left. Then the chain from a robot's MJCF through its excitation design and lab runs to its fits
# and gap report (CHAIN_PRIORITY), the MJCF of a robot that designs an excitation first: with the design in about
# 40 s, the robots' chains fill both cores to the end of the build.
CHAIN_PRIORITY = 1
MESH_PRIORITY = CHAIN_PRIORITY + 1


def chain_priority(wildcards):
    """A robot's MJCF heads the longest chain when it gates an excitation design."""
    return CHAIN_PRIORITY if excitation_targets(wildcards.robot) else 0


# sysid and gap_report split a round of the loop over two processes (the new rung's two ways, the diagnosis's
# candidates, the figures). A job that asks for two cores starts only when both are free, and in a first build the
# other jobs keep one busy until the last CoACD job ends, so that the fits and reports would wait for it and run last,
# one after the other. Without kept work (a first build: every rung is new, the rest of the DAG runs beside) they
# ask for one; a round, which reads most of its work back and runs alone, gets ``most``. The outputs are the same
# bytes.
def round_threads(most, kept):
    def threads(wildcards):
        return most if os.path.isdir(kept(wildcards)) else 1

    return threads

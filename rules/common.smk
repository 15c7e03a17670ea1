# Helpers shared by the rules files: config, wildcards and built files mapped onto paths.
# The logic lives in src/sim2real; the rules files hold only rules.
import functools
import glob
import os

import sim2real.assets.collision as _sim2real_collision
import sim2real.assets.meshes as _sim2real_meshes
import sim2real.assets.robot_config as _sim2real_robot_config
import sim2real.excitation.names as _sim2real_design_names
import sim2real.excitation.config as _sim2real_excitation_config
import sim2real.identification.model_config as _sim2real_model_config
import sim2real.measurements.campaigns as _sim2real_campaigns
import sim2real.files as _sim2real_files
from sim2real.errors import InputError
import sim2real.assets.urdf as _sim2real_urdf

from snakemake.utils import validate

validate(config, "../schemas/config.schema.yaml")

ROBOTS = list(config["robots"])
# Measurement campaigns per robot: configs/{robot}/measurements.yaml is the default one (reports under
# results/{robot}/), each configs/{robot}/campaigns/<name>.yaml another (reports under results/{robot}/<name>/).
CAMPAIGNS = {robot: _sim2real_campaigns.robot_campaigns(robot) for robot in ROBOTS}


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
    campaign=_sim2real_campaigns.wildcard_pattern(
        [c.name for cs in CAMPAIGNS.values() for c in cs if c.prefix]
    ),


def all_targets():
    """Every output `snakemake all` builds: the one list of the workflow's targets, stage by stage for every
    configured robot (each stage's function below), then the fleet view over all robots.
    """
    targets = []
    for robot in ROBOTS:
        for stage_targets in (
            urdf_targets,
            mjcf_targets,
            collision_targets,
            usd_targets,
            lab_truth_targets,
            campaign_sysid_targets,
            campaign_report_targets,
            dr_targets,
            excitation_targets,
        ):
            targets.extend(stage_targets(robot))
    return targets + ["results/fleet.json", "results/fleet.md"]


# ---- robot sources and settings -------------------------------------------------


def robot_dir(robot):
    return f"robots/{robot}"


def robot_config(robot):
    return f"configs/{robot}/robot.yaml"


@functools.cache
def robot_settings(robot):
    """configs/{robot}/robot.yaml as a dict, validated against schemas/robot.schema.yaml; read once per run."""
    return _sim2real_robot_config.read_robot_config(robot_config(robot))


def robot_params(wildcards):
    """What the MJCF, USD, sysid and excitation jobs read of robot.yaml, as a param rather than the file as an input:
    they rerun when one of these settings changes, not after an edit of a comment or of ``collision`` (the CoACD
    jobs and the collision report take that section as their own params; new parts rerun the MJCF through them).
    """
    return {
        key: value
        for key, value in robot_settings(wildcards.robot).items()
        if key != "collision"
    }


def robot_xacro(robot):
    return robot_settings(robot).get("xacro", f"{robot_dir(robot)}/{robot}.urdf.xacro")


def xacro_includes(wildcards):
    """Every Xacro file the robot's Xacro may include (its own folder and robots/common)."""
    files = set(glob.glob(f"{robot_dir(wildcards.robot)}/**/*.xacro", recursive=True))
    files |= set(glob.glob("robots/common/**/*.xacro", recursive=True))
    return sorted(files)


def measurement_list(robot):
    return f"configs/{robot}/measurements.yaml"


def model_ladder(robot):
    return f"configs/{robot}/model.yaml"


@functools.cache
def has_model(robot):
    """Whether the robot has a model ladder (configs/{robot}/model.yaml): then its runs are fitted."""
    return os.path.exists(model_ladder(robot))


def identifies(robot):
    """Robots with measurements and a model ladder get identified parameters and calibrated assets."""
    return os.path.exists(measurement_list(robot)) and has_model(robot)


# ---- URDF: nominal (variant "") and calibrated (variant "calibrated/") trees -----


def calibration_file(wildcards):
    return (
        [f"results/{wildcards.robot}/sysid/calibration.yaml"]
        if wildcards.variant
        else []
    )


def urdf_xacro_args(wildcards):
    args = dict(robot_settings(wildcards.robot).get("xacro_args") or {})
    args["calibration"] = calibration_file(wildcards)[0] if wildcards.variant else ""
    return args


def nominal_urdf(robot):
    return f"results/{robot}/{robot}.urdf"


# ---- meshes: the list comes from the nominal URDF through the urdf checkpoint ---

_MESH_NAMES_CACHE = {}


def robot_meshes(robot):
    """{kind: {name: package uri}} of the robot's nominal URDF (read once per URDF version)."""
    urdf = checkpoints.urdf.get(robot=robot, variant="").output[0]
    key = (urdf, os.path.getmtime(urdf))
    if key not in _MESH_NAMES_CACHE:
        _MESH_NAMES_CACHE[key] = _sim2real_urdf.mesh_names(urdf)
    return _MESH_NAMES_CACHE[key]


def mesh_uri(kind):
    def uri(wildcards):
        return robot_meshes(wildcards.robot)[kind][wildcards.name]

    return uri


_MESH_LINKS_CACHE = {}


def mesh_links(kind):
    """The links that use the {name} mesh of ``kind`` (named by a mesh job's error)."""

    def links(wildcards):
        urdf = checkpoints.urdf.get(robot=wildcards.robot, variant="").output[0]
        key = (urdf, os.path.getmtime(urdf))
        if key not in _MESH_LINKS_CACHE:
            _MESH_LINKS_CACHE[key] = _sim2real_meshes.mesh_links(urdf)
        return _MESH_LINKS_CACHE[key][kind][wildcards.name]

    return links


def mesh_source(kind):
    def source(wildcards):
        return str(_sim2real_urdf.resolve_package_uri(mesh_uri(kind)(wildcards)))

    return source


def visual_mesh_dirs(robot):
    return [
        f"results/{robot}/meshes/visual/{name}"
        for name in sorted(robot_meshes(robot)["visual"])
    ]


# ---- collision: CoACD parts, one job per URDF collision mesh -------------------


def collision_section(robot):
    return robot_settings(robot).get("collision") or {}


def coacd_settings(wildcards):
    """Settings of one mesh (defaults < collision.coacd < collision.overrides.<name>) as plain params."""
    return _sim2real_collision.mesh_settings(
        collision_section(wildcards.robot),
        wildcards.name,
        robot_config(wildcards.robot),
    ).as_params()


def coacd_source(wildcards):
    """The mesh CoACD decomposes: the detailed visual mesh of the same name or the coarse collision STL."""
    if coacd_settings(wildcards)["source"] == "collision":
        return f"results/{wildcards.robot}/meshes/collision/{wildcards.name}.stl"
    if wildcards.name not in robot_meshes(wildcards.robot)["visual"]:
        raise InputError(
            robot_config(wildcards.robot),
            f"collision.overrides.{wildcards.name}",
            f"no visual mesh named '{wildcards.name}' to decompose",
            "set 'source: collision' for this mesh",
        )
    return f"results/{wildcards.robot}/meshes/visual/{wildcards.name}"


def coacd_dirs(robot):
    """{collision mesh name: convex parts directory} of every URDF collision mesh."""
    return {
        name: f"results/{robot}/collision/{name}"
        for name in sorted(robot_meshes(robot)["collision"])
    }


def collision_part_dirs(robot):
    """{URDF collision mesh URI: its CoACD parts directory}: the collision geoms of the MJCF and the USD."""
    return {
        uri: f"results/{robot}/collision/{name}"
        for name, uri in sorted(robot_meshes(robot)["collision"].items())
    }


# ---- system identification ------------------------------------------------------


def campaign_measurements(wildcards):
    """The measurement list of the {campaign} wildcard ("" = configs/{robot}/measurements.yaml)."""
    return _sim2real_campaigns.campaign_file(
        wildcards.robot, _sim2real_campaigns.campaign_name(wildcards.campaign)
    )


def campaign_report_targets(robot):
    """gap.json and gap.md of every campaign of the robot."""
    return [
        f"results/{robot}/{c.prefix}{name}"
        for c in CAMPAIGNS[robot]
        for name in ("gap.json", "gap.md")
    ]


def campaign_sysid_targets(robot):
    """The fitted ladder and calibration of every campaign, where the robot has a model ladder."""
    if not has_model(robot):
        return []
    return [
        f"results/{robot}/{c.prefix}sysid/{name}"
        for c in CAMPAIGNS[robot]
        for name in ("ladder.json", "calibration.yaml")
    ]


@functools.cache
def fleet_campaigns():
    """Every identified campaign of every robot, with the files the fleet view reads (read once per run)."""
    return [
        {
            "robot": c.robot,
            "campaign": c.name,
            "arm": c.arm,
            "date": c.date,
            "measurements": c.measurements,
            "report": f"{c.results}gap.md",
            "ladder": f"{c.results}sysid/ladder.json",
            "params": f"{c.results}sysid/params.yaml",
        }
        for robot in ROBOTS
        if has_model(robot)
        for c in CAMPAIGNS[robot]
    ]


def fleet_ladders(wildcards):
    return [c["ladder"] for c in fleet_campaigns()]


def fleet_params(wildcards):
    return [c["params"] for c in fleet_campaigns()]


def fleet_records(wildcards):
    return fleet_campaigns()


def identified_params(wildcards):
    """The calibrated MJCF also takes what the URDF cannot hold (armature, delay, gear) from sysid."""
    return [f"results/{wildcards.robot}/sysid/params.yaml"] if wildcards.variant else []


def identified_params_if_any(wildcards):
    """sysid/params.yaml where the robot is identified (randomization coverage), else nothing."""
    return (
        [f"results/{wildcards.robot}/sysid/params.yaml"]
        if identifies(wildcards.robot)
        else []
    )


def sysid_ladder(wildcards):
    """The campaign's ladder and diagnosis section of the gap report and the last rung's residuals, where the
    robot has a model ladder."""
    return (
        [
            f"results/{wildcards.robot}/{wildcards.campaign}sysid/ladder.json",
            f"results/{wildcards.robot}/{wildcards.campaign}sysid/residuals.npz",
        ]
        if has_model(wildcards.robot)
        else []
    )


# ---- measurements and the virtual lab -------------------------------------------


def measurement_files(wildcards):
    """Every run table of the campaign's measurement list and its metadata YAML (so lab runs get built)."""
    from sim2real.measurements import load_measurement_list

    files = []
    for entry in load_measurement_list(campaign_measurements(wildcards)):
        files += [entry.path.as_posix(), entry.path.with_suffix(".yaml").as_posix()]
    return files


def bag_topics(wildcards):
    """ROS 2 topics of configs/{robot}/measurements.yaml (`ros2:`), with the package defaults."""
    from sim2real.measurements.bags import ros2_topics

    return ros2_topics(measurement_list(wildcards.robot))


@functools.cache
def lab_excitation_designs(robot):
    """{(scenario, run): design} of configs/{robot}/lab.yaml; read once per run."""
    from sim2real.lab import excitation_designs

    return excitation_designs(lab_config(robot))


@functools.cache
def lab_scenario(robot, scenario):
    """A scenario of configs/{robot}/lab.yaml, defaults merged and checked (an error names the file, the key and the
    fix), with the lab's joints, as plain data; read once per run."""
    from sim2real.lab import lab_scenario as read_scenario

    return read_scenario(lab_config(robot), scenario)


def lab_config(robot):
    return f"configs/{robot}/lab.yaml"


def lab_scenario_params(wildcards):
    """What a lab run or truth reads of lab.yaml, its scenario's settings with the defaults, as a param rather than
    the file as an input: a comment or another scenario's edit reruns none of its runs.
    """
    return lab_scenario(wildcards.robot, wildcards.scenario)


def lab_run_excitation(wildcards):
    """The designed excitation a lab run plays (lab.yaml `runs: [{..., excitation: <design>}]`), if any."""
    design = lab_excitation_designs(wildcards.robot).get(
        (wildcards.scenario, wildcards.run)
    )
    return [f"results/{wildcards.robot}/excitation/{design}.csv"] if design else []


def lab_truth_targets(robot):
    """truth.yaml of every lab scenario the robot's campaigns measure (no comparing rule reads it)."""
    from sim2real.measurements import load_measurement_list

    prefix = f"results/{robot}/lab/"
    scenarios = {
        entry.path.as_posix()[len(prefix) :].split("/")[0]
        for c in CAMPAIGNS[robot]
        for entry in load_measurement_list(c.measurements)
        if entry.path.as_posix().startswith(prefix)
    }
    return [f"{prefix}{scenario}/truth.yaml" for scenario in sorted(scenarios)]


# ---- excitation design -------------------------------------------------------------


def excitation_config(robot):
    return f"configs/{robot}/excitation.yaml"


@functools.cache
def model_config(robot):
    """configs/{robot}/model.yaml parsed and validated (sim2real.identification.model_config), None without one;
    read once per run."""
    if not has_model(robot):
        return None
    return _sim2real_model_config.load_model_config(model_ladder(robot))


def model_effects(robot):
    """The effects of configs/{robot}/model.yaml in order ([] without one)."""
    ladder = model_config(robot)
    return list(ladder.effects) if ladder is not None else []


def design_model_effects(wildcards):
    """What an excitation design reads of model.yaml, the effects whose columns it makes identifiable, as a param
    rather than the file as an input: a comment, a fit setting or an effect that adds no column (link_inertia,
    payload, actuation_delay, sensor_delay) reruns no design; another effect added, removed or moved does.
    """
    return _sim2real_excitation_config.identification_effects(
        model_effects(wildcards.robot)
    )


@functools.cache
def excitation_design(robot, design):
    """A design of configs/{robot}/excitation.yaml, defaults merged and checked (an error names the file, the key
    and the fix), as plain data; read once per run. A separating design takes the file's defaults.
    """
    separating = _sim2real_design_names.confounded_pair(design) is not None
    return _sim2real_excitation_config.load_design(
        excitation_config(robot), design, allow_default=separating
    ).spec()


def design_params(wildcards):
    """What a design's jobs read of excitation.yaml, the design's own entry with the defaults, as a param rather than
    the file as an input: a comment or another design's entry reruns no design."""
    return excitation_design(wildcards.robot, wildcards.design)


def design_start(wildcards):
    """Where a design starts: its design for friction alone (rule excitation_start)."""
    return [f"results/{wildcards.robot}/excitation/{wildcards.design}.start.npz"]


def separation_ladder(wildcards):
    """The diagnosis a separating design (separate-<a>-vs-<b>) reads its two fitted candidates from."""
    if _sim2real_design_names.confounded_pair(wildcards.design) is None:
        return []
    return [f"results/{wildcards.robot}/sysid/ladder.json"]


def excitation_targets(robot):
    """Every design of configs/{robot}/excitation.yaml (the file is validated by the rule itself)."""
    path = excitation_config(robot)
    if not os.path.exists(path):
        return []
    designs = (_sim2real_files.read_yaml(path) or {}).get("designs") or {}
    return [f"results/{robot}/excitation/{name}.csv" for name in sorted(designs)] + [
        f"results/{robot}/excitation/{name}.md" for name in sorted(designs)
    ]


# ---- scheduling -------------------------------------------------------------------
# Of the jobs ready to run, Snakemake starts those of highest priority first, and a rule's priority does not pass to
# the jobs it waits for. Every robot's mesh conversions and CoACD jobs go first (MESH_PRIORITY): they are most of a
# cold build's work, and a long CoACD job left for the end (the UR5's wrist, 60-75 s) ran alone on one core while
# nothing else was left. Then the chain from a robot's MJCF through its excitation design and lab runs to its fits
# and gap report (CHAIN_PRIORITY), the MJCF of a robot that designs an excitation first: with the design in about
# 40 s, the robots' chains fill both cores to the end of the build.
CHAIN_PRIORITY = 1
MESH_PRIORITY = CHAIN_PRIORITY + 1


def chain_priority(wildcards):
    """A robot's MJCF heads the longest chain when it gates an excitation design."""
    return CHAIN_PRIORITY if excitation_targets(wildcards.robot) else 0


def sysid_fits(wildcards):
    """Where a campaign's sysid keeps its rungs and diagnoses for the next round (sim2real.cache.FitCache)."""
    return f"results/{wildcards.robot}/{wildcards.campaign}sysid/fits"


def gap_kept(wildcards):
    """Where a campaign's gap report keeps its replays and figures for the next round."""
    return f"results/{wildcards.robot}/{wildcards.campaign}gap/kept"


# sysid and gap_report split a round of the loop over two processes (the new rung's two ways, the diagnosis's
# candidates, the figures). A job that asks for two cores starts only when both are free, and in a first build the
# other jobs keep one busy until the last CoACD job ends: the fits and reports then waited for it and ran last, one
# after the other. Without kept work (a first build: every rung is new, the rest of the DAG runs beside) they ask
# for one; a round, which reads most of its work back and runs alone, gets ``most``. The outputs are the same bytes.
def round_threads(most, kept):
    def threads(wildcards):
        return most if os.path.isdir(kept(wildcards)) else 1

    return threads


# ---- the stages' final outputs (all_targets) ---------------------------------------


def urdf_targets(robot):
    return [nominal_urdf(robot)]


def mjcf_targets(robot):
    """The MJCF and its scene, nominal and (where the robot is identified) calibrated."""
    return [
        f"results/{robot}/{variant}mjcf/{robot}.xml"
        for variant in ("", "calibrated/")
        if not variant or identifies(robot)
    ] + [f"results/{robot}/mjcf/scene.xml"]


def collision_targets(robot):
    return [f"results/{robot}/collision/report.json"]


def usd_targets(robot):
    """The USD and its equivalence check with the URDF and the MJCF, nominal and (identified) calibrated."""
    return [
        f"results/{robot}/{variant}{name}"
        for variant in ("", "calibrated/")
        if not variant or identifies(robot)
        for name in (f"usd/{robot}.usda", "equivalence.json")
    ]


def dr_targets(robot):
    return [
        f"results/{robot}/dr.json",
        f"results/{robot}/dr/coverage.json",
        f"results/{robot}/dr/summary.svg",
    ]

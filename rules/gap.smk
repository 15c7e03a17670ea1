# Gap report: measurements (configs/{robot}/measurements.yaml) vs the model -> gap.json, gap.md, figures.
# ROS 2 bags under data/{robot}/bags/ are converted to measurement runs first.
import os


wildcard_constraints:
    bag="[A-Za-z0-9_.-]+",


def measurement_list(robot):
    return f"configs/{robot}/measurements.yaml"


def measurement_files(wildcards):
    """Every run table of measurements.yaml and its metadata YAML (so lab runs get built)."""
    from pathlib import Path

    from sim2real.measurements import load_measurement_list

    files = []
    for entry in load_measurement_list(measurement_list(wildcards.robot)):
        files += [entry.path.as_posix(), entry.path.with_suffix(".yaml").as_posix()]
    return files


def sysid_ladder(wildcards):
    """The precomputed ladder/diagnosis section, when the robot has a model ladder and a rule makes it."""
    target = f"results/{wildcards.robot}/sysid/ladder.json"
    produced = any(str(o).endswith("sysid/ladder.json") for r in workflow.rules for o in r.output)
    has_model = os.path.exists(f"configs/{wildcards.robot}/model.yaml")
    return [target] if produced and has_model else []


def bag_topics(wildcards):
    from sim2real.io import read_validated_yaml

    ros2 = read_validated_yaml(measurement_list(wildcards.robot), "measurements.schema.yaml").get("ros2", {})
    return ros2


rule bag_to_run:
    input:
        bag="data/{robot}/bags/{bag}.mcap",
        measurements="configs/{robot}/measurements.yaml",
    output:
        run="results/{robot}/bags/{bag}.parquet",
        meta="results/{robot}/bags/{bag}.yaml",
    params:
        joint_topic=lambda w: bag_topics(w).get("joint_topic", "/joint_states"),
        command_topic=lambda w: bag_topics(w).get("command_topic"),
    log:
        "results/{robot}/logs/bag_to_run/{bag}.log",
    benchmark:
        "results/{robot}/benchmarks/bag_to_run/{bag}.tsv"
    script:
        "../scripts/bag_to_run.py"


rule gap_report:
    input:
        urdf="results/{robot}/{robot}.urdf",
        mjcf="results/{robot}/mjcf/{robot}.xml",
        measurements="configs/{robot}/measurements.yaml",
        runs=measurement_files,
        ladder=sysid_ladder,
    output:
        json="results/{robot}/gap.json",
        md="results/{robot}/gap.md",
        torque=report(
            "results/{robot}/gap/torque.png",
            caption="../report/gap_torque.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
        residual_velocity=report(
            "results/{robot}/gap/residual_velocity.png",
            caption="../report/gap_residual_velocity.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
        regimes=report(
            "results/{robot}/gap/regimes.png",
            caption="../report/gap_regimes.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
        ladder=report(
            "results/{robot}/gap/ladder.png",
            caption="../report/gap_ladder.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
    log:
        "results/{robot}/logs/gap_report.log",
    benchmark:
        "results/{robot}/benchmarks/gap_report.tsv"
    script:
        "../scripts/gap_report.py"


STAGE_TARGETS.append(lambda robot: [f"results/{robot}/gap.json", f"results/{robot}/gap.md"])

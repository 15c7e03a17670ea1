# Xacro -> validated URDF.
# One rule serves two trees: the nominal one, results/{robot}/{robot}.urdf, and the calibrated one,
# results/{robot}/calibrated/{robot}.urdf, which passes calibration:=results/{robot}/sysid/calibration.yaml.
# The rule is a checkpoint: the mesh stage reads the list of meshes from the nominal URDF through
# checkpoints.urdf.get(), which does not make a mesh job depend on the URDF's content, so editing an
# inertial reruns URDF and MJCF but no mesh job.
import glob
import os

import sim2real.io as _sim2real_io


wildcard_constraints:
    variant="(calibrated/)?",


def robot_settings(robot):
    """configs/{robot}/robot.yaml as a dict (validated by the MJCF stage)."""
    return _sim2real_io.read_yaml(robot_config(robot))


def robot_xacro(robot):
    return robot_settings(robot).get("xacro", f"{robot_dir(robot)}/{robot}.urdf.xacro")


def xacro_includes(wildcards):
    """Every Xacro file the robot's Xacro may include (its own folder and robots/common)."""
    files = set(glob.glob(f"{robot_dir(wildcards.robot)}/**/*.xacro", recursive=True))
    files |= set(glob.glob("robots/common/**/*.xacro", recursive=True))
    return sorted(files)


def calibration_file(wildcards):
    return (
        [f"results/{wildcards.robot}/sysid/calibration.yaml"]
        if wildcards.variant
        else []
    )


def urdf_xacro_args(wildcards):
    args = {
        k: v
        for k, v in (robot_settings(wildcards.robot).get("xacro_args") or {}).items()
    }
    args["calibration"] = calibration_file(wildcards)[0] if wildcards.variant else ""
    return args


def nominal_urdf(robot):
    return f"results/{robot}/{robot}.urdf"


checkpoint urdf:
    input:
        xacro=lambda w: robot_xacro(w.robot),
        includes=xacro_includes,
        calibration=calibration_file,
    output:
        "results/{robot}/{variant}{robot}.urdf",
    log:
        "results/{robot}/{variant}logs/urdf.log",
    benchmark:
        "results/{robot}/{variant}benchmarks/urdf.tsv"
    params:
        args=urdf_xacro_args,
    script:
        "../scripts/build_urdf.py"


STAGE_TARGETS.append(lambda robot: [nominal_urdf(robot)])

# System identification: the model ladder of configs/{robot}/model.yaml fitted on the measured runs
# (role: fit), judged on role: holdout, with the diagnosis of the missing effect; the fitted values
# become results/{robot}/sysid/calibration.yaml, from which the URDF/MJCF rules build
# results/{robot}/calibrated/. Never reads the lab's truth.yaml.
import os

import sim2real.io as _sysid_io


def sysid_measurement_list(robot):
    return f"configs/{robot}/measurements.yaml"


def sysid_run_files(wildcards):
    """Every run listed in measurements.yaml and its metadata file beside it."""
    data = _sysid_io.read_yaml(sysid_measurement_list(wildcards.robot)) or {}
    files = []
    for run in data.get("runs", []):
        path = run["path"]
        files += [path, os.path.splitext(path)[0] + ".yaml"]
    return sorted(files)


rule sysid:
    input:
        urdf="results/{robot}/{robot}.urdf",
        robot_config=lambda w: robot_config(w.robot),
        model="configs/{robot}/model.yaml",
        measurements=lambda w: sysid_measurement_list(w.robot),
        runs=sysid_run_files,
    output:
        ladder="results/{robot}/sysid/ladder.json",
        params="results/{robot}/sysid/params.yaml",
        calibration="results/{robot}/sysid/calibration.yaml",
    log:
        "results/{robot}/logs/sysid.log",
    benchmark:
        "results/{robot}/benchmarks/sysid.tsv"
    script:
        "../scripts/sysid.py"


STAGE_TARGETS.append(
    lambda robot: (
        [
            f"results/{robot}/sysid/ladder.json",
            f"results/{robot}/sysid/calibration.yaml",
        ]
        if has_measurements(robot)
        else []
    )
)

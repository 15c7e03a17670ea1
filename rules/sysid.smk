# System identification: the model ladder of configs/{robot}/model.yaml fitted on the measured runs
# (role: fit), judged on role: holdout, with the diagnosis of the missing effect; the fitted values
# become results/{robot}/sysid/calibration.yaml, from which the URDF/MJCF rules build
# results/{robot}/calibrated/. Never reads the lab's truth.yaml.


rule sysid:
    input:
        urdf="results/{robot}/{robot}.urdf",
        robot_config=lambda w: robot_config(w.robot),
        model="configs/{robot}/model.yaml",
        measurements=lambda w: measurement_list(w.robot),
        runs=measurement_files,
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
        if identifies(robot)
        else []
    )
)

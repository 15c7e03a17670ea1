# System identification: the model ladder of configs/{robot}/model.yaml fitted on the measured runs
# (role: fit), judged on role: holdout, with the diagnosis of the missing effect; the fitted values
# become results/{robot}/sysid/calibration.yaml, from which the URDF/MJCF rules build
# results/{robot}/calibrated/. Never reads the lab's truth.yaml.
# One job per campaign: {campaign} is "" for configs/{robot}/measurements.yaml (results/{robot}/sysid/)
# and "<name>/" for configs/{robot}/campaigns/<name>.yaml (results/{robot}/<name>/sysid/).


rule sysid:
    input:
        urdf="results/{robot}/{robot}.urdf",
        model="configs/{robot}/model.yaml",
        prepared="results/{robot}/{campaign}prepared_runs.npz",
    output:
        ladder="results/{robot}/{campaign}sysid/ladder.json",
        params="results/{robot}/{campaign}sysid/params.yaml",
        calibration="results/{robot}/{campaign}sysid/calibration.yaml",
        # the last rung's residual on every run: the gap report describes the model being calibrated
        residuals="results/{robot}/{campaign}sysid/residuals.npz",
    log:
        "results/{robot}/logs/{campaign}sysid.log",
    benchmark:
        "results/{robot}/benchmarks/{campaign}sysid.tsv"
    # the diagnosis fits its candidates side by side (sim2real.identification.diagnosis.trial_fits)
    priority: CHAIN_PRIORITY
    threads: round_threads(2, get_sysid_fits)
    resources:
        # forked workers share the parent's pages, but the benchmark sums every process's resident set
        mem_mb=1536,
        runtime=5,
    params:
        # the rungs and diagnoses of the last round, read back when their inputs did not change
        fits=get_sysid_fits,
        robot=get_robot_params,
        robot_config=lambda w: robot_config(w.robot),
    script:
        "../scripts/sysid.py"

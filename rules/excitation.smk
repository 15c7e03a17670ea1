# Excitation design: configs/{robot}/excitation.yaml -> an optimised, collision-checked identification
# trajectory (CSV at the controller rate, a ROS 2 JointTrajectory, a report), for the model of
# configs/{robot}/model.yaml on the built URDF and MJCF (CoACD collision parts). Each design's jobs take its own
# entry of excitation.yaml (defaults merged) and model.yaml's effects as params: an edit reruns the designs it changes.
# A design named separate-<a>-vs-<b> is the run that tells two candidates the diagnosis could not tell apart
# (gap.md names it): it reads their fits from the ladder. Every design starts from its own design for the nominal
# model and friction alone (excitation_start), which reads nothing of model.yaml nor of the ladder: a change of the
# model's effects designs from there in seconds, and the result is the same bytes whatever was designed before.


rule excitation_start:
    input:
        urdf="results/{robot}/{robot}.urdf",
        mjcf="results/{robot}/mjcf/{robot}.xml",
    output:
        start="results/{robot}/excitation/{design}.start.npz",
    log:
        "results/{robot}/logs/excitation/{design}.start.log",
    benchmark:
        "results/{robot}/benchmarks/excitation/{design}.start.tsv"
    priority: CHAIN_PRIORITY
    threads: 1
    resources:
        mem_mb=2048,
        runtime=30,
    params:
        design=get_design,
        config=lambda w: excitation_config(w.robot),
        robot=get_robot_params,
        robot_config=lambda w: robot_config(w.robot),
    script:
        "../scripts/excitation_start.py"


rule excitation:
    input:
        urdf="results/{robot}/{robot}.urdf",
        mjcf="results/{robot}/mjcf/{robot}.xml",
        ladder=get_separation_ladder,
        start=get_design_start,
    output:
        csv="results/{robot}/excitation/{design}.csv",
        trajectory="results/{robot}/excitation/{design}.trajectory.yaml",
        json="results/{robot}/excitation/{design}.json",
        md="results/{robot}/excitation/{design}.md",
        figure=report(
            "results/{robot}/excitation/{design}.png",
            caption="../report/excitation.rst",
            category="Excitation",
            subcategory="{robot}",
        ),
    log:
        "results/{robot}/logs/excitation/{design}.log",
    benchmark:
        "results/{robot}/benchmarks/excitation/{design}.tsv"
    priority: CHAIN_PRIORITY
    threads: 1
    resources:
        mem_mb=2048,
        runtime=30,
    params:
        design=get_design,
        config=lambda w: excitation_config(w.robot),
        robot=get_robot_params,
        robot_config=lambda w: robot_config(w.robot),
        model_effects=get_design_model_effects,
        model_config=lambda w: model_ladder(w.robot),
    script:
        "../scripts/excitation.py"

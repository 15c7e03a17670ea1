# Gap report: measurements (configs/{robot}/measurements.yaml) vs the model -> gap.json, gap.md (its first
# screen also as HTML for the Snakemake report), figures.
# ROS 2 bags under data/{robot}/bags/ are converted to measurement runs first; the runs are prepared once
# (filtered, on a uniform grid, checked against the URDF) for the gap report and the sysid rule, so that a
# round of the loop (a change of model.yaml) reads them back instead of preparing them again.
# One report per campaign: {campaign} is "" for measurements.yaml (results/{robot}/gap.json) and
# "<name>/" for configs/{robot}/campaigns/<name>.yaml (results/{robot}/<name>/gap.json).


rule bag_to_run:
    input:
        bag="data/{robot}/bags/{bag}.mcap",
        measurements="configs/{robot}/measurements.yaml",
    output:
        run="results/{robot}/bags/{bag}.parquet",
        meta="results/{robot}/bags/{bag}.yaml",
    log:
        "results/{robot}/logs/bag_to_run/{bag}.log",
    benchmark:
        "results/{robot}/benchmarks/bag_to_run/{bag}.tsv"
    threads: 1
    resources:
        mem_mb=1024,
        runtime=10,
    params:
        topics=get_bag_topics,
    script:
        "../scripts/bag_to_run.py"


rule prepare_runs:
    input:
        urdf="results/{robot}/{robot}.urdf",
        measurements=get_measurement_list,
        runs=get_measurement_files,
    output:
        prepared="results/{robot}/{campaign}prepared_runs.npz",
    log:
        "results/{robot}/logs/{campaign}prepare_runs.log",
    benchmark:
        "results/{robot}/benchmarks/{campaign}prepare_runs.tsv"
    priority: CHAIN_PRIORITY
    threads: 1
    resources:
        mem_mb=1024,
        runtime=5,
    script:
        "../scripts/prepare_runs.py"


rule gap_report:
    input:
        urdf="results/{robot}/{robot}.urdf",
        mjcf="results/{robot}/mjcf/{robot}.xml",
        prepared="results/{robot}/{campaign}prepared_runs.npz",
        ladder=get_sysid_ladder,
    output:
        json="results/{robot}/{campaign}gap.json",
        md="results/{robot}/{campaign}gap.md",
        first_screen=report(
            "results/{robot}/{campaign}gap/first_screen.html",
            caption="../report/gap_first_screen.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
        torque=report(
            "results/{robot}/{campaign}gap/torque.png",
            caption="../report/gap_torque.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
        residual_velocity=report(
            "results/{robot}/{campaign}gap/residual_velocity.png",
            caption="../report/gap_residual_velocity.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
        residual_time=report(
            "results/{robot}/{campaign}gap/residual_time.png",
            caption="../report/gap_residual_time.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
        regimes=report(
            "results/{robot}/{campaign}gap/regimes.png",
            caption="../report/gap_regimes.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
        ladder=report(
            "results/{robot}/{campaign}gap/ladder.png",
            caption="../report/gap_ladder.rst",
            category="Gap report",
            subcategory="{robot}",
        ),
    log:
        "results/{robot}/logs/{campaign}gap_report.log",
    benchmark:
        "results/{robot}/benchmarks/{campaign}gap_report.tsv"
    # the figures are drawn in worker processes while the replays run (sim2real.report.figures.GapFigures)
    priority: CHAIN_PRIORITY
    threads: round_threads(2, get_gap_kept)
    resources:
        mem_mb=1024,
        runtime=5,
    params:
        # the replays and figures of the last report, read back when what they show did not change
        kept=get_gap_kept,
    script:
        "../scripts/gap_report.py"

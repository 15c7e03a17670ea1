# Virtual lab: configs/{robot}/lab.yaml scenarios simulated in the built MJCF -> measurement runs.
# truth.yaml holds the hidden values; no rule that compares, fits or diagnoses may take it as input.


localrules:
    lab_truth,


rule lab_run:
    input:
        mjcf="results/{robot}/mjcf/{robot}.xml",
        excitation=get_lab_run_excitation,
    output:
        run="results/{robot}/lab/{scenario}/{run}.parquet",
        meta="results/{robot}/lab/{scenario}/{run}.yaml",
    log:
        "results/{robot}/logs/lab_run/{scenario}/{run}.log",
    benchmark:
        "results/{robot}/benchmarks/lab_run/{scenario}/{run}.tsv"
    priority: CHAIN_PRIORITY
    threads: 1
    resources:
        mem_mb=1024,
        runtime=5,
    params:
        # the scenario's own settings: an edit of lab.yaml reruns the runs of the scenarios it changes
        scenario=get_lab_scenario,
        config=lambda w: lab_config(w.robot),
    script:
        "../scripts/lab_run.py"


rule lab_truth:
    input:
        mjcf="results/{robot}/mjcf/{robot}.xml",
    output:
        truth="results/{robot}/lab/{scenario}/truth.yaml",
    log:
        "results/{robot}/logs/lab_truth/{scenario}.log",
    benchmark:
        "results/{robot}/benchmarks/lab_truth/{scenario}.tsv"
    threads: 1
    resources:
        mem_mb=256,
        runtime=2,
    params:
        scenario=get_lab_scenario,
        config=lambda w: lab_config(w.robot),
    script:
        "../scripts/lab_truth.py"


ruleorder: lab_truth > lab_run

# The fleet view: every robot's campaigns side by side (holdout error per rung, identified values with
# their intervals) and what changed between consecutive campaigns of the same arm, counted only where
# the two intervals do not overlap. Reads each campaign's sysid ladder.json and params.yaml.


localrules:
    fleet,


rule fleet:
    input:
        ladders=get_fleet_ladders,
        params=get_fleet_params,
        schema="schemas/fleet.schema.json",
    output:
        json="results/fleet.json",
        md="results/fleet.md",
        figure=report(
            "results/fleet/parameters.png",
            caption="../report/fleet.rst",
            category="Fleet",
        ),
    log:
        "results/logs/fleet.log",
    benchmark:
        "results/benchmarks/fleet.tsv"
    threads: 1
    resources:
        mem_mb=512,
        runtime=2,
    params:
        campaigns=get_fleet_records,
    script:
        "../scripts/fleet.py"

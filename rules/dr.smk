# Domain randomization: configs/{robot}/dr.yaml resolved against the built MJCF.
#
# dr.json depends only on the MJCF and dr.yaml (fast, no wait for the fit). The coverage check
# against identified values is a separate rule (dr_summary) that reads sysid/params.yaml where the
# robot is identified (measurements and a model ladder); elsewhere the check is skipped and says so.
# config["dr"]["strict_coverage"]: true turns uncovered identified values into an error.


localrules:
    dr_resolve,
    dr_summary,


rule dr_resolve:
    input:
        config="configs/{robot}/dr.yaml",
        mjcf="results/{robot}/mjcf/{robot}.xml",
        schema="schemas/dr.schema.json",
    output:
        "results/{robot}/dr.json",
    log:
        "results/{robot}/logs/dr_resolve.log",
    benchmark:
        "results/{robot}/benchmarks/dr_resolve.tsv"
    threads: 1
    resources:
        mem_mb=768,
        runtime=2,
    params:
        robot="{robot}",
    script:
        "../scripts/dr_resolve.py"


rule dr_summary:
    input:
        dr="results/{robot}/dr.json",
        identified=get_identified_params_if_any,
    output:
        coverage="results/{robot}/dr/coverage.json",
        table=report(
            "results/{robot}/dr/summary.tsv",
            caption="../report/dr_summary.rst",
            category="Domain randomization",
            subcategory="{robot}",
            labels={"robot": "{robot}", "view": "table"},
        ),
        figure=report(
            "results/{robot}/dr/summary.svg",
            caption="../report/dr_summary.rst",
            category="Domain randomization",
            subcategory="{robot}",
            labels={"robot": "{robot}", "view": "figure"},
        ),
    log:
        "results/{robot}/logs/dr_summary.log",
    benchmark:
        "results/{robot}/benchmarks/dr_summary.tsv"
    threads: 1
    resources:
        mem_mb=256,
        runtime=2,
    params:
        strict=config.get("dr", {}).get("strict_coverage", False),
    script:
        "../scripts/dr_summary.py"

# CoACD convex decomposition, one job per URDF collision mesh, and the collision report.
# A job's inputs are its source mesh only (the built visual mesh directory or the coarse collision STL)
# and its settings are params: it reruns when that mesh or its settings change, never on a URDF edit.
# The number of convex parts is known only after CoACD ran, so the MJCF and USD stages take the parts
# directories as inputs and read their manifests (no checkpoint to re-evaluate). Wall times differ from run to
# run, so they (and the report table that shows them) live under benchmarks/, apart from the
# byte-reproducible outputs.


localrules:
    collision_report,


rule coacd:
    input:
        get_coacd_source,
    output:
        parts=directory("results/{robot}/collision/{name}"),
        timing="results/{robot}/benchmarks/coacd/{name}.json",
    log:
        "results/{robot}/logs/coacd/{name}.log",
    benchmark:
        "results/{robot}/benchmarks/coacd/{name}.tsv"
    wildcard_constraints:
        name="[A-Za-z0-9_-]+",
    priority: MESH_PRIORITY
    threads: 1
    resources:
        mem_mb=2048,
        runtime=15,
    params:
        settings=get_coacd_settings,
    script:
        "../scripts/coacd.py"


rule collision_report:
    input:
        parts=get_coacd_parts,
        timing=get_coacd_timings,
    output:
        json="results/{robot}/collision/report.json",
        table=report(
            "results/{robot}/benchmarks/collision_summary.tsv",
            caption="../report/collision_summary.rst",
            category="Collision",
            labels={"robot": "{robot}", "table": "CoACD parts"},
        ),
    log:
        "results/{robot}/logs/collision_report.log",
    benchmark:
        "results/{robot}/benchmarks/collision_report.tsv"
    threads: 1
    resources:
        mem_mb=256,
        runtime=2,
    params:
        names=get_coacd_names,
        tolerance=get_collision_tolerance,
    script:
        "../scripts/collision_report.py"

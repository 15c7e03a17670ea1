# URDF + built visual meshes + CoACD parts -> UsdPhysics asset (robot layer + geometry layer), and the
# cross-format equivalence check of URDF, MJCF and USD (fails the build naming the joint or link).


def usd_visual_dirs(wildcards):
    return visual_mesh_dirs(wildcards.robot)


def usd_collision_inputs(wildcards):
    return sorted(
        f for files in coacd_collision_meshes(wildcards.robot).values() for f in files
    )


rule usd:
    input:
        urdf="results/{robot}/{robot}.urdf",
        config=lambda w: robot_config(w.robot),
        visual=usd_visual_dirs,
        collision=usd_collision_inputs,
    output:
        usda="results/{robot}/usd/{robot}.usda",
        geometry="results/{robot}/usd/{robot}_geometry.usda",
    log:
        "results/{robot}/logs/usd.log",
    benchmark:
        "results/{robot}/benchmarks/usd.tsv"
    params:
        collision_meshes=lambda w: coacd_collision_meshes(w.robot),
    script:
        "../scripts/build_usd.py"


rule equivalence:
    input:
        urdf="results/{robot}/{robot}.urdf",
        mjcf="results/{robot}/mjcf/{robot}.xml",
        usd="results/{robot}/usd/{robot}.usda",
        geometry="results/{robot}/usd/{robot}_geometry.usda",
    output:
        "results/{robot}/equivalence.json",
    log:
        "results/{robot}/logs/equivalence.log",
    benchmark:
        "results/{robot}/benchmarks/equivalence.tsv"
    script:
        "../scripts/equivalence.py"


STAGE_TARGETS.append(
    lambda robot: [
        f"results/{robot}/usd/{robot}.usda",
        f"results/{robot}/equivalence.json",
    ]
)

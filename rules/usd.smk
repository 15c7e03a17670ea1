# URDF + built visual meshes + CoACD parts -> UsdPhysics asset (robot layer + geometry layer), for the
# nominal tree and for the calibrated one (results/{robot}/calibrated/usd/), and the
# cross-format equivalence check of URDF, MJCF and USD (fails the build naming the joint or link).


rule usd:
    input:
        urdf="results/{robot}/{variant}{robot}.urdf",
        visual=get_visual_mesh_dirs,
        collision=get_collision_parts,
    output:
        usda="results/{robot}/{variant}usd/{robot}.usda",
        geometry="results/{robot}/{variant}usd/{robot}_geometry.usda",
    log:
        "results/{robot}/{variant}logs/usd.log",
    benchmark:
        "results/{robot}/{variant}benchmarks/usd.tsv"
    threads: 1
    resources:
        mem_mb=512,
        runtime=3,
    params:
        collision_dirs=get_collision_part_dirs,
        robot=get_robot_params,
        robot_config=lambda w: robot_config(w.robot),
    script:
        "../scripts/build_usd.py"


rule equivalence:
    input:
        urdf="results/{robot}/{variant}{robot}.urdf",
        mjcf="results/{robot}/{variant}mjcf/{robot}.xml",
        usd="results/{robot}/{variant}usd/{robot}.usda",
        geometry="results/{robot}/{variant}usd/{robot}_geometry.usda",
    output:
        "results/{robot}/{variant}equivalence.json",
    log:
        "results/{robot}/{variant}logs/equivalence.log",
    benchmark:
        "results/{robot}/{variant}benchmarks/equivalence.tsv"
    threads: 1
    resources:
        mem_mb=1024,
        runtime=3,
    script:
        "../scripts/equivalence.py"

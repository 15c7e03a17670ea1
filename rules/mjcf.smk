# URDF + converted meshes + configs/{robot}/robot.yaml -> MJCF and scene.xml (menagerie conventions).
# Same rule for the nominal (results/{robot}/mjcf/) and calibrated (results/{robot}/calibrated/mjcf/) trees;
# both use the meshes under results/{robot}/meshes/.


rule mjcf:
    input:
        urdf="results/{robot}/{variant}{robot}.urdf",
        visual=get_visual_mesh_dirs,
        collision=get_collision_parts,
        params=get_identified_params,
    output:
        xml="results/{robot}/{variant}mjcf/{robot}.xml",
        scene="results/{robot}/{variant}mjcf/scene.xml",
    log:
        "results/{robot}/{variant}logs/mjcf.log",
    benchmark:
        "results/{robot}/{variant}benchmarks/mjcf.tsv"
    priority: chain_priority
    threads: 1
    resources:
        mem_mb=1024,
        runtime=3,
    params:
        collision_dirs=get_collision_part_dirs,
        robot=get_robot_params,
        robot_config=lambda w: robot_config(w.robot),
    script:
        "../scripts/build_mjcf.py"

# URDF + converted meshes + configs/{robot}/robot.yaml -> MJCF and scene.xml (menagerie conventions).
# Same rule for the nominal (results/{robot}/mjcf/) and calibrated (results/{robot}/calibrated/mjcf/) trees;
# both use the meshes under results/{robot}/meshes/.


def mjcf_collision_meshes(robot):
    """URDF collision mesh URI -> list of mesh files: the CoACD convex parts (rules/collision.smk)."""
    return coacd_collision_meshes(robot)


def mjcf_collision_inputs(wildcards):
    return sorted(
        f for files in mjcf_collision_meshes(wildcards.robot).values() for f in files
    )


def identified_params(wildcards):
    """The calibrated tree also takes what the URDF cannot hold (armature, delay, gear) from sysid."""
    return [f"results/{wildcards.robot}/sysid/params.yaml"] if wildcards.variant else []


rule mjcf:
    input:
        urdf="results/{robot}/{variant}{robot}.urdf",
        config=lambda w: robot_config(w.robot),
        visual=lambda w: visual_mesh_dirs(w.robot),
        collision=mjcf_collision_inputs,
        params=identified_params,
    output:
        xml="results/{robot}/{variant}mjcf/{robot}.xml",
        scene="results/{robot}/{variant}mjcf/scene.xml",
    log:
        "results/{robot}/{variant}logs/mjcf.log",
    benchmark:
        "results/{robot}/{variant}benchmarks/mjcf.tsv"
    params:
        collision_meshes=lambda w: mjcf_collision_meshes(w.robot),
    script:
        "../scripts/build_mjcf.py"


STAGE_TARGETS.append(
    lambda robot: [
        f"results/{robot}/{variant}mjcf/{robot}.xml"
        for variant in ("", "calibrated/")
        if not variant or has_measurements(robot)
    ]
    + [f"results/{robot}/mjcf/scene.xml"]
)

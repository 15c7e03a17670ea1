# Mesh conversion, one job per mesh file: a visual mesh (DAE, OBJ, STL, glTF/GLB, ...) -> OBJ per material +
# parts.json, a collision mesh -> binary STL.
# The list of meshes comes from the nominal URDF via checkpoints.urdf.get(); a mesh job's only input is
# its source mesh file (and its URI as a param), so URDF edits that keep the mesh URIs rerun no mesh job.


localrules:
    collision_mesh,


rule visual_mesh:
    input:
        get_mesh_source("visual"),
    output:
        directory("results/{robot}/meshes/visual/{name}"),
    log:
        "results/{robot}/logs/visual_mesh/{name}.log",
    benchmark:
        "results/{robot}/benchmarks/visual_mesh/{name}.tsv"
    wildcard_constraints:
        name="[^/]+",
    priority: MESH_PRIORITY
    threads: 1
    resources:
        mem_mb=256,
        runtime=2,
    params:
        uri=get_mesh_uri("visual"),
        links=get_mesh_links("visual"),
    script:
        "../scripts/convert_visual_mesh.py"


rule collision_mesh:
    input:
        get_mesh_source("collision"),
    output:
        "results/{robot}/meshes/collision/{name}.stl",
    log:
        "results/{robot}/logs/collision_mesh/{name}.log",
    benchmark:
        "results/{robot}/benchmarks/collision_mesh/{name}.tsv"
    wildcard_constraints:
        name="[^/]+",
    priority: MESH_PRIORITY
    threads: 1
    resources:
        mem_mb=256,
        runtime=1,
    params:
        uri=get_mesh_uri("collision"),
        links=get_mesh_links("collision"),
    script:
        "../scripts/convert_collision_mesh.py"

# Mesh conversion, one job per mesh file: visual DAE -> OBJ per material + parts.json, collision STL copy.
# The list of meshes comes from the nominal URDF via checkpoints.urdf.get(); a mesh job's only input is
# its source mesh file (and its URI as a param), so URDF edits that keep the mesh URIs rerun no mesh job.
import sim2real.urdf as _sim2real_urdf

_MESH_NAMES_CACHE = {}


def robot_meshes(robot):
    """{kind: {name: package uri}} of the robot's nominal URDF (read once per URDF version)."""
    urdf = checkpoints.urdf.get(robot=robot, variant="").output[0]
    key = (urdf, os.path.getmtime(urdf))
    if key not in _MESH_NAMES_CACHE:
        _MESH_NAMES_CACHE[key] = _sim2real_urdf.mesh_names(urdf)
    return _MESH_NAMES_CACHE[key]


def mesh_uri(kind):
    def uri(wildcards):
        return robot_meshes(wildcards.robot)[kind][wildcards.name]

    return uri


def mesh_source(kind):
    def source(wildcards):
        return str(_sim2real_urdf.resolve_package_uri(mesh_uri(kind)(wildcards)))

    return source


def visual_mesh_dirs(robot):
    return [
        f"results/{robot}/meshes/visual/{name}"
        for name in sorted(robot_meshes(robot)["visual"])
    ]


def collision_mesh_files(robot):
    """{collision mesh URI: [mesh files]} (one STL per URDF collision mesh)."""
    return {
        uri: [f"results/{robot}/meshes/collision/{name}.stl"]
        for name, uri in sorted(robot_meshes(robot)["collision"].items())
    }


rule visual_mesh:
    input:
        mesh_source("visual"),
    output:
        directory("results/{robot}/meshes/visual/{name}"),
    log:
        "results/{robot}/logs/visual_mesh/{name}.log",
    benchmark:
        "results/{robot}/benchmarks/visual_mesh/{name}.tsv"
    wildcard_constraints:
        name="[^/]+",
    params:
        uri=mesh_uri("visual"),
    script:
        "../scripts/convert_visual_mesh.py"


rule collision_mesh:
    input:
        mesh_source("collision"),
    output:
        "results/{robot}/meshes/collision/{name}.stl",
    log:
        "results/{robot}/logs/collision_mesh/{name}.log",
    benchmark:
        "results/{robot}/benchmarks/collision_mesh/{name}.tsv"
    wildcard_constraints:
        name="[^/]+",
    params:
        uri=mesh_uri("collision"),
    script:
        "../scripts/convert_collision_mesh.py"

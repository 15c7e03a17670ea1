# CoACD convex decomposition, one checkpoint job per URDF collision mesh, and the collision report.
# A job's inputs are its source mesh only (the built visual mesh directory or the coarse collision STL)
# and its settings are params: it reruns when that mesh or its settings change, never on a URDF edit.
# The jobs are checkpoints because the number of convex parts is known only after CoACD ran;
# coacd_collision_meshes() reads it back for the MJCF and USD stages.
import sim2real.collision as _sim2real_collision


def collision_section(robot):
    return robot_settings(robot).get("collision") or {}


def coacd_settings(wildcards):
    """Settings of one mesh (defaults < collision.coacd < collision.overrides.<name>) as plain params."""
    return _sim2real_collision.mesh_settings(
        collision_section(wildcards.robot),
        wildcards.name,
        robot_config(wildcards.robot),
    ).as_params()


def coacd_source(wildcards):
    """The mesh CoACD decomposes: the detailed visual mesh of the same name or the coarse collision STL."""
    if coacd_settings(wildcards)["source"] == "collision":
        return f"results/{wildcards.robot}/meshes/collision/{wildcards.name}.stl"
    if wildcards.name not in robot_meshes(wildcards.robot)["visual"]:
        raise ValueError(
            f"{robot_config(wildcards.robot)}: collision.overrides.{wildcards.name}: no visual mesh named "
            f"'{wildcards.name}' to decompose. Fix: set 'source: collision' for this mesh"
        )
    return f"results/{wildcards.robot}/meshes/visual/{wildcards.name}"


def coacd_dirs(robot):
    """{collision mesh name: convex parts directory} of every URDF collision mesh."""
    return {
        name: f"results/{robot}/collision/{name}"
        for name in sorted(robot_meshes(robot)["collision"])
    }


def coacd_collision_meshes(robot):
    """{URDF collision mesh URI: [convex part files]} (waits for the decomposition checkpoints)."""
    return {
        uri: [
            str(f)
            for f in _sim2real_collision.part_files(
                checkpoints.coacd.get(robot=robot, name=name).output[0]
            )
        ]
        for name, uri in sorted(robot_meshes(robot)["collision"].items())
    }


checkpoint coacd:
    input:
        coacd_source,
    output:
        parts=directory("results/{robot}/collision/{name}"),
        timing="results/{robot}/collision/timing/{name}.json",
    log:
        "results/{robot}/logs/coacd/{name}.log",
    benchmark:
        "results/{robot}/benchmarks/coacd/{name}.tsv"
    wildcard_constraints:
        name="[A-Za-z0-9_-]+",
    params:
        settings=coacd_settings,
    script:
        "../scripts/coacd.py"


rule collision_report:
    input:
        parts=lambda w: list(coacd_dirs(w.robot).values()),
        timing=lambda w: [
            f"results/{w.robot}/collision/timing/{name}.json"
            for name in coacd_dirs(w.robot)
        ],
    output:
        json="results/{robot}/collision/report.json",
        table=report(
            "results/{robot}/collision/summary.tsv",
            caption="../report/collision_summary.rst",
            category="Collision",
            labels={"robot": "{robot}", "table": "CoACD parts"},
        ),
    log:
        "results/{robot}/logs/collision_report.log",
    benchmark:
        "results/{robot}/benchmarks/collision_report.tsv"
    params:
        names=lambda w: list(coacd_dirs(w.robot)),
        tolerance=lambda w: collision_section(w.robot).get("tolerance") or {},
    script:
        "../scripts/collision_report.py"


STAGE_TARGETS.append(lambda robot: [f"results/{robot}/collision/report.json"])

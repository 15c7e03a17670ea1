# Xacro -> validated URDF.
# One rule serves two trees: the nominal one, results/{robot}/{robot}.urdf, and the calibrated one,
# results/{robot}/calibrated/{robot}.urdf, which passes calibration:=results/{robot}/sysid/calibration.yaml.
# The rule is a checkpoint: the mesh stage reads the list of meshes from the nominal URDF through
# checkpoints.urdf.get(), which does not make a mesh job depend on the URDF's content, so editing an
# inertial reruns URDF and MJCF but no mesh job.


checkpoint urdf:
    input:
        xacro=get_xacro,
        includes=get_xacro_includes,
        calibration=get_calibration,
    output:
        "results/{robot}/{variant}{robot}.urdf",
    log:
        "results/{robot}/{variant}logs/urdf.log",
    benchmark:
        "results/{robot}/{variant}benchmarks/urdf.tsv"
    threads: 1
    resources:
        mem_mb=512,
        runtime=2,
    params:
        args=get_xacro_args,
    script:
        "../scripts/build_urdf.py"

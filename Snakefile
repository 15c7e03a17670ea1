# sim2real: every robot asset and every gap report is a build output of this DAG.
from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "configs/config.yaml"


validate(config, "schemas/config.schema.yaml")


include: "rules/common.smk"
include: "rules/urdf.smk"
include: "rules/meshes.smk"
include: "rules/mjcf.smk"
include: "rules/collision.smk"
include: "rules/usd.smk"
include: "rules/lab.smk"
include: "rules/sysid.smk"
include: "rules/gap.smk"
include: "rules/dr.smk"
include: "rules/excitation.smk"
include: "rules/fleet.smk"


rule all:
    default_target: True
    input:
        all_targets(),

# sim2real: every robot asset and every gap report is a build output of this DAG.
from snakemake.utils import min_version

import sim2real.cli as _sim2real_cli

min_version("9.0")
# An InputError (bad input: file, key, fix) reaches the user as its one-line message, printed last; its
# traceback goes to the rule's log (sim2real.cli: rule_entry in every script, these two hooks here).
_sim2real_cli.one_line_input_errors()


configfile: "configs/config.yaml"


report: "report/workflow.rst"


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


onerror:
    _sim2real_cli.input_errors_last(log)

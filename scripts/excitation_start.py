"""Snakemake script: where an excitation.yaml design starts for any model (sim2real.excitation)."""

from sim2real.cli import rule_entry
from sim2real.excitation.files import ExcitationInputs, build_excitation_start

with rule_entry(snakemake):
    build_excitation_start(
        ExcitationInputs(
            snakemake.wildcards.robot,
            snakemake.params.config,
            snakemake.wildcards.design,
            snakemake.input.urdf,
            snakemake.input.mjcf,
            snakemake.params.robot_config,
            robot_settings=snakemake.params.robot,
            design_spec=snakemake.params.design,
        ),
        snakemake.output.start,
    )

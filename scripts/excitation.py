"""Snakemake script: excitation.yaml design -> trajectory CSV, ROS 2 JointTrajectory, report (sim2real.excitation)."""

from sim2real.cli import rule_entry
from sim2real.excitation.files import ExcitationInputs, build_excitation

with rule_entry(snakemake):
    build_excitation(
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
        snakemake.params.model_config,
        {key: str(value) for key, value in snakemake.output.items()},
        ladder=snakemake.input.ladder[0] if snakemake.input.ladder else None,
        model_effects=snakemake.params.model_effects,
        start=snakemake.input.start[0] if snakemake.input.start else None,
    )

"""Snakemake script: simulate one virtual-lab run (sim2real.lab.run_lab_scenario_run)."""

from sim2real.cli import rule_entry
from sim2real.lab import run_lab_scenario_run

with rule_entry(snakemake):
    run_lab_scenario_run(
        snakemake.input.mjcf,
        snakemake.params.config,
        snakemake.wildcards.robot,
        snakemake.wildcards.scenario,
        snakemake.wildcards.run,
        snakemake.output.run,
        excitation=snakemake.input.excitation[0] if snakemake.input.excitation else None,
        scenario_spec=snakemake.params.scenario,
    )

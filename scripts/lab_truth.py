"""Snakemake script: the lab scenario's hidden values (sim2real.lab.write_truth). Tests read it; no comparison does."""

from sim2real.cli import rule_entry
from sim2real.lab import write_truth

with rule_entry(snakemake):
    write_truth(snakemake.params.config, snakemake.input.mjcf, snakemake.wildcards.scenario, snakemake.output.truth,
                scenario_spec=snakemake.params.scenario)

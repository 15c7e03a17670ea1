"""Snakemake script: a measurement list -> its runs prepared against the URDF (sim2real.measurements)."""

from sim2real.cli import rule_entry
from sim2real.measurements import prepare_for_model, write_prepared_runs

with rule_entry(snakemake):
    write_prepared_runs(
        snakemake.output.prepared, prepare_for_model(snakemake.input.measurements, snakemake.input.urdf)
    )

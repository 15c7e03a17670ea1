"""Snakemake script: the lab scenario's hidden values (sim2real.lab.write_truth). Tests read it; no comparison does."""

import logging

from sim2real.lab import write_truth

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
write_truth(snakemake.input.config, snakemake.input.mjcf, snakemake.wildcards.scenario, snakemake.output.truth)

"""Snakemake script: URDF vs MJCF vs USD (sim2real.assets.equivalence.check_equivalence); fails on a mismatch."""

from sim2real.cli import rule_entry
from sim2real.assets.equivalence import check_equivalence

with rule_entry(snakemake):
    check_equivalence(snakemake.input.urdf, snakemake.input.mjcf, snakemake.input.usd, snakemake.output[0])

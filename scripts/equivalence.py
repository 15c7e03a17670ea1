"""Snakemake script: URDF vs MJCF vs USD (sim2real.equivalence.check_equivalence); fails on a mismatch."""

import logging

from sim2real.equivalence import check_equivalence

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
try:
    check_equivalence(snakemake.input.urdf, snakemake.input.mjcf, snakemake.input.usd, snakemake.output[0])
except Exception:
    logging.exception("failed")  # the log names the mismatching joint or link
    raise

"""Snakemake script: Xacro -> validated URDF (sim2real.urdf.build_urdf)."""

import logging

from sim2real.urdf import build_urdf

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
try:
    build_urdf(snakemake.input.xacro, snakemake.output[0], dict(snakemake.params.args))
except Exception:
    logging.exception("failed")  # the log names the bad input too
    raise

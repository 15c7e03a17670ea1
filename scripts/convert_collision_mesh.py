"""Snakemake script: collision STL -> normalized binary STL (sim2real.meshes)."""

import logging

from sim2real.meshes import convert_collision_mesh

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
try:
    convert_collision_mesh(snakemake.input[0], snakemake.output[0], snakemake.params.uri)
except Exception:
    logging.exception("failed")  # the log names the bad input too
    raise

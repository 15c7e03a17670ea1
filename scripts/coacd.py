"""Snakemake script: one mesh -> CoACD convex parts + parts.json (sim2real.collision.decompose)."""

import logging

from sim2real.collision import MeshSettings, decompose, write_timing

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
try:
    result = decompose(
        snakemake.input[0], MeshSettings.from_params(snakemake.params.settings), snakemake.output.parts,
        mesh_name=snakemake.wildcards.name,
    )
    write_timing(snakemake.output.timing, snakemake.wildcards.name, result.seconds)
    logging.info("%s: %d parts in %.1f s, %s", snakemake.wildcards.name, len(result.part_files), result.seconds, result.fidelity)
except Exception:
    logging.exception("failed")  # the log names the bad input too
    raise

"""Snakemake script: one mesh -> CoACD convex parts + parts.json (sim2real.assets.collision.decompose)."""

import logging

from sim2real.cli import rule_entry
from sim2real.assets.collision import MeshSettings, decompose, write_timing

with rule_entry(snakemake):
    result = decompose(
        snakemake.input[0], MeshSettings.from_params(snakemake.params.settings), snakemake.output.parts,
        mesh_name=snakemake.wildcards.name,
    )
    write_timing(snakemake.output.timing, snakemake.wildcards.name, result.seconds)
    logging.info("%s: %d parts in %.1f s, %s", snakemake.wildcards.name, len(result.part_files), result.seconds, result.fidelity)

"""Snakemake script: a collision mesh -> binary STL (sim2real.assets.meshes)."""

from sim2real.cli import rule_entry
from sim2real.assets.meshes import convert_collision_mesh

with rule_entry(snakemake):
    convert_collision_mesh(snakemake.input[0], snakemake.output[0], snakemake.params.uri, snakemake.params.links)

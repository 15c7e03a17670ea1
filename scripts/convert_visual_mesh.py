"""Snakemake script: a visual mesh -> one OBJ per material + parts.json (sim2real.assets.meshes)."""

from sim2real.cli import rule_entry
from sim2real.assets.meshes import convert_visual_mesh

with rule_entry(snakemake):
    convert_visual_mesh(snakemake.input[0], snakemake.output[0], snakemake.params.uri, snakemake.params.links)

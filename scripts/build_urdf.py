"""Snakemake script: Xacro -> validated URDF (sim2real.assets.urdf.build_urdf)."""

from sim2real.cli import rule_entry
from sim2real.assets.urdf import build_urdf

with rule_entry(snakemake):
    build_urdf(snakemake.input.xacro, snakemake.output[0], dict(snakemake.params.args))

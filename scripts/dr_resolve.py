"""Snakemake script: configs/{robot}/dr.yaml + built MJCF -> results/{robot}/dr.json."""

import logging

from sim2real.cli import rule_entry
from sim2real.dr import resolve_files
from sim2real.files import write_json

snakemake = globals()["snakemake"]

with rule_entry(snakemake):
    resolved = resolve_files(snakemake.input.config, snakemake.input.mjcf, robot=snakemake.params.robot)
    write_json(snakemake.output[0], resolved)
    for channel in resolved["physics"]:
        logging.info("%s/%s: %d elements", channel["term"], channel["channel"], len(channel["targets"]))

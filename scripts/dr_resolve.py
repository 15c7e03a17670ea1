"""Snakemake script: configs/{robot}/dr.yaml + built MJCF -> results/{robot}/dr.json."""

import contextlib

from sim2real.dr import resolve_files
from sim2real.io import write_json

snakemake = globals()["snakemake"]

with open(snakemake.log[0], "w", encoding="utf-8") as log, contextlib.redirect_stderr(log):
    resolved = resolve_files(snakemake.input.config, snakemake.input.mjcf, robot=snakemake.params.robot)
    write_json(snakemake.output[0], resolved)
    for channel in resolved["physics"]:
        print(f"{channel['term']}/{channel['channel']}: {len(channel['targets'])} elements", file=log)

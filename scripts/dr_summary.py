"""Snakemake script: dr.json (+ sysid/params.yaml when built) -> coverage, summary table and figure."""

import logging

from sim2real.cli import rule_entry
from sim2real.dr import build_summary

snakemake = globals()["snakemake"]

with rule_entry(snakemake):
    identified = list(snakemake.input.identified)
    coverage = build_summary(
        snakemake.input.dr,
        identified[0] if identified else None,
        snakemake.output.coverage,
        snakemake.output.table,
        snakemake.output.figure,
        strict=bool(snakemake.params.strict),
    )
    logging.info("coverage: %s", coverage["status"])
    for warning in coverage["warnings"]:
        logging.warning("%s", warning)

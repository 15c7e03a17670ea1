"""Snakemake script: every campaign's sysid ladder and params -> fleet.json, fleet.md, figure (sim2real.report.fleet)."""

import logging

from sim2real.cli import rule_entry
from sim2real.report.fleet import build_fleet

with rule_entry(snakemake):
    fleet = build_fleet(snakemake.params.campaigns, snakemake.output.json, snakemake.output.md, snakemake.output.figure)
    for arm in fleet["arms"]:
        for change in arm["changes"]:
            logging.info("%s", change["text"])
    logging.info("%d arm(s), %d campaign(s), %d change(s)", fleet["summary"]["arms"], fleet["summary"]["campaigns"],
                 fleet["summary"]["changes"])

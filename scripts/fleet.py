"""Snakemake script: every campaign's sysid ladder and params -> fleet.json, fleet.md, figure (sim2real.fleet)."""

import logging

from sim2real.fleet import build_fleet

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
fleet = build_fleet(snakemake.params.campaigns, snakemake.output.json, snakemake.output.md, snakemake.output.figure)
for arm in fleet["arms"]:
    for change in arm["changes"]:
        logging.info("%s", change["text"])
logging.info("%d arm(s), %d campaign(s), %d change(s)", fleet["summary"]["arms"], fleet["summary"]["campaigns"],
             fleet["summary"]["changes"])

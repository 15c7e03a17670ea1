"""Snakemake script: per-mesh CoACD manifests -> collision report.json + summary table."""

import logging

from sim2real.collision import Tolerance, collision_report

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
try:
    names = list(snakemake.params.names)
    report = collision_report(
        dict(zip(names, snakemake.input.parts, strict=True)),
        dict(zip(names, snakemake.input.timing, strict=True)),
        Tolerance(**snakemake.params.tolerance),
        snakemake.output.json,
        snakemake.output.table,
    )
    for name in report["flagged"]:
        logging.warning("%s misses the shape: %s", name, "; ".join(report["meshes"][name]["flag_reasons"]))
except Exception:
    logging.exception("failed")  # the log names the bad input too
    raise

"""Snakemake script: measured runs + model ladder -> ladder.json, params.yaml, calibration.yaml (sim2real.sysid)."""

import logging

from sim2real.sysid import run_sysid

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
document = run_sysid(
    snakemake.wildcards.robot,
    snakemake.input.urdf,
    snakemake.input.robot_config,
    snakemake.input.model,
    snakemake.input.measurements,
    snakemake.output.ladder,
    snakemake.output.params,
    snakemake.output.calibration,
)
logging.info("diagnosis: %s", document.get("diagnosis", {}).get("verdict"))

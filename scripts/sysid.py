"""Snakemake script: measured runs + model ladder -> ladder.json, params.yaml, calibration.yaml (sim2real.identification.sysid)."""

import logging

from sim2real.cli import rule_entry
from sim2real.identification.sysid import run_sysid

with rule_entry(snakemake):
    document = run_sysid(
        snakemake.wildcards.robot,
        snakemake.input.urdf,
        snakemake.params.robot_config,
        snakemake.input.model,
        snakemake.input.prepared,
        snakemake.output.ladder,
        snakemake.output.params,
        snakemake.output.calibration,
        threads=snakemake.threads,
        cache_dir=snakemake.params.fits,
        residuals_npz=snakemake.output.residuals,
        robot_settings=snakemake.params.robot,
    )
    diagnosis = document.get("diagnosis") or {}
    named = (diagnosis.get("candidates") or [{}])[0].get("effect") if diagnosis.get("status") == "add_effect" else None
    logging.info("diagnosis: %s%s (gap.md words it)", diagnosis.get("status"), f", add {named}" if named else "")

"""Snakemake script: measured runs + model ladder -> ladder.json, params.yaml, calibration.yaml (sim2real.identification.sysid)."""

import logging

from sim2real.cli import rule_entry
from sim2real.identification.diagnosis import Diagnosis, candidate_named
from sim2real.identification.ladder_rows import LadderDocument
from sim2real.identification.sysid import SysidFiles, run_sysid

with rule_entry(snakemake):
    files = SysidFiles(
        urdf=snakemake.input.urdf,
        robot_config=snakemake.params.robot_config,
        model_config=snakemake.input.model,
        measurements=snakemake.input.prepared,
        ladder=snakemake.output.ladder,
        params=snakemake.output.params,
        calibration=snakemake.output.calibration,
        residuals=snakemake.output.residuals,
    )
    document = run_sysid(snakemake.wildcards.robot, files, threads=snakemake.threads, cache_dir=snakemake.params.fits,
                         robot_settings=snakemake.params.robot)
    found = LadderDocument.from_document(document).body.diagnosis
    diagnosis = Diagnosis.from_document(found) if found is not None else None
    named = candidate_named(diagnosis)
    logging.info("diagnosis: %s%s (gap.md words it)", diagnosis.status if diagnosis else None,
                 f", add {named.effect}" if named else "")

"""Snakemake script: URDF + meshes + CoACD parts -> UsdPhysics asset (sim2real.assets.usd.build_usd)."""

import logging

from sim2real.cli import rule_entry
from sim2real.assets.collision import parts_by_uri
from sim2real.assets.meshes import BuiltMeshes
from sim2real.assets.usd import build_usd

with rule_entry(snakemake):
    summary = build_usd(
        snakemake.input.urdf,
        snakemake.params.robot_config,
        BuiltMeshes.of(list(snakemake.input.visual), parts_by_uri(snakemake.params.collision_dirs)),
        snakemake.output.usda,
        snakemake.output.geometry,
        robot_settings=snakemake.params.robot,
    )
    logging.info("bodies %s; joints %s", summary["bodies"], summary["joints"])

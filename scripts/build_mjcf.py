"""Snakemake script: URDF + meshes -> MJCF + scene.xml (sim2real.mjcf.build_mjcf)."""

import logging

from sim2real.collision import parts_by_uri
from sim2real.effects import spec_edit_from_params
from sim2real.mjcf import build_mjcf

logging.basicConfig(filename=snakemake.log[0], filemode="w", level=logging.INFO, format="%(levelname)s %(message)s")
try:
    build_mjcf(
        snakemake.input.urdf,
        snakemake.input.config,
        list(snakemake.input.visual),
        parts_by_uri(snakemake.params.collision_dirs),
        snakemake.output.xml,
        snakemake.output.scene,
        spec_edit=spec_edit_from_params(snakemake.input.params[0]) if snakemake.input.params else None,
    )
except Exception:
    logging.exception("failed")  # the log names the bad input too
    raise

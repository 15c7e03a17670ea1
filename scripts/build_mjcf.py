"""Snakemake script: URDF + meshes -> MJCF + scene.xml (sim2real.assets.mjcf.build_mjcf)."""

from sim2real.cli import rule_entry
from sim2real.assets.collision import parts_by_uri
from sim2real.assets.meshes import BuiltMeshes
from sim2real.identification.effects import spec_edit_from_params
from sim2real.assets.mjcf import build_mjcf

with rule_entry(snakemake):
    build_mjcf(
        snakemake.input.urdf,
        snakemake.params.robot_config,
        BuiltMeshes.of(list(snakemake.input.visual), parts_by_uri(snakemake.params.collision_dirs)),
        snakemake.output.xml,
        snakemake.output.scene,
        spec_edit=spec_edit_from_params(snakemake.input.params[0]) if snakemake.input.params else None,
        robot_settings=snakemake.params.robot,
    )

"""Snakemake script: measurements vs model -> gap.json, gap.md, figures (sim2real.report.gap.build_gap_report)."""

from sim2real.cli import rule_entry
from sim2real.report.gap import build_gap_report

with rule_entry(snakemake):
    build_gap_report(
        snakemake.wildcards.robot,
        snakemake.input.urdf,
        snakemake.input.mjcf,
        snakemake.input.prepared,
        snakemake.output.json,
        snakemake.output.md,
        {"torque": snakemake.output.torque, "residual_velocity": snakemake.output.residual_velocity,
         "residual_time": snakemake.output.residual_time,
         "regimes": snakemake.output.regimes, "ladder": snakemake.output.ladder},
        precomputed_path=snakemake.input.ladder[0] if snakemake.input.ladder else None,
        threads=snakemake.threads,
        cache_dir=snakemake.params.kept,
        residuals_path=snakemake.input.ladder[1] if len(snakemake.input.ladder) > 1 else None,
    )

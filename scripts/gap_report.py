"""Snakemake script: measurements vs model -> gap.json, gap.md, its first screen, figures (sim2real.report.gap.build_gap_report)."""

from sim2real.cli import rule_entry
from sim2real.report.gap import GapInputs, build_gap_report

with rule_entry(snakemake):
    build_gap_report(
        GapInputs(
            robot=snakemake.wildcards.robot,
            urdf=snakemake.input.urdf,
            mjcf=snakemake.input.mjcf,
            measurements=snakemake.input.prepared,
            ladder=snakemake.input.ladder[0] if snakemake.input.ladder else None,
            residuals=snakemake.input.ladder[1] if len(snakemake.input.ladder) > 1 else None,
        ),
        snakemake.output.json,
        snakemake.output.md,
        {"torque": snakemake.output.torque, "residual_velocity": snakemake.output.residual_velocity,
         "residual_time": snakemake.output.residual_time,
         "regimes": snakemake.output.regimes, "ladder": snakemake.output.ladder},
        threads=snakemake.threads,
        cache_dir=snakemake.params.kept,
        first_screen_html=snakemake.output.first_screen,
    )

"""Snakemake script: dr.json (+ sysid/params.yaml when built) -> coverage, summary table and figure."""

import contextlib

from sim2real.dr import build_summary

snakemake = globals()["snakemake"]

with open(snakemake.log[0], "w", encoding="utf-8") as log, contextlib.redirect_stderr(log):
    identified = list(snakemake.input.identified)
    coverage = build_summary(
        snakemake.input.dr,
        identified[0] if identified else None,
        snakemake.output.coverage,
        snakemake.output.table,
        snakemake.output.figure,
        strict=bool(snakemake.params.strict),
    )
    print(f"coverage: {coverage['status']}", file=log)
    for warning in coverage["warnings"]:
        print(f"WARNING: {warning}", file=log)

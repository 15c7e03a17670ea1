"""The randomization summary for the report: one row per randomized element with its nominal value,
absolute range and identified value, as a tab-separated table and an SVG figure (the ``dr_summary``
rule: :func:`build_summary`). matplotlib is imported only when a figure is drawn.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.dr.coverage import coverage_summary
from sim2real.dr.parameters import fmt
from sim2real.dr.resolve import load_resolved


def summary_rows(resolved: Mapping[str, Any], coverage: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per randomized element (vector components flattened), with the identified value."""
    identified = {(r["term"], r["channel"], r["element"]): r for r in coverage.get("records", [])}
    rows = []
    for channel in resolved["physics"]:
        for target in channel["targets"]:
            match = identified.get((channel["term"], channel["channel"], target["name"]))
            for axis, ((low, high), nominal) in enumerate(zip(target["range"], target["nominal"])):
                suffix = "xyz"[axis] if len(target["range"]) == 3 else ""
                rows.append(
                    {
                        "term": channel["term"],
                        "channel": channel["channel"] + (f".{suffix}" if suffix else ""),
                        "element": target["name"],
                        "unit": channel["unit"],
                        "mode": channel["mode"],
                        "distribution": channel["distribution"],
                        "operation": channel["operation"],
                        "nominal": nominal,
                        "low": low,
                        "high": high,
                        "identified": match["value"] if match else None,
                        "identified_low": match["interval"][0] if match else None,
                        "identified_high": match["interval"][1] if match else None,
                        "covered": match["covered"] if match else None,
                    }
                )
    return rows


def summary_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Tab-separated table of :func:`summary_rows` (empty cells for missing values)."""
    columns = ["term", "channel", "element", "unit", "mode", "distribution", "operation", "nominal", "low", "high",
               "identified", "identified_low", "identified_high", "covered"]

    def cell(value: Any) -> str:
        if value is None:
            return ""
        if isinstance(value, float):
            return fmt(value)
        return str(value).lower() if isinstance(value, bool) else str(value)

    return "\n".join(["\t".join(columns)] + ["\t".join(cell(row[c]) for c in columns) for row in rows]) + "\n"


def plot_summary(rows: Sequence[Mapping[str, Any]], title: str, target: str | Path) -> None:
    """One panel per randomized channel: the absolute range of each element (bar), its nominal
    value (black tick) and the identified interval when known (green inside / red outside)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim2real.files import atomic_path

    channels: dict[str, list[Mapping[str, Any]]] = {}
    for row in rows:
        channels.setdefault(f"{row['term']} / {row['channel']}", []).append(row)
    heights = [max(len(v), 1) * 0.22 + 0.6 for v in channels.values()] or [1.0]
    with matplotlib.rc_context({"svg.hashsalt": "sim2real-dr", "font.size": 7}):
        fig, axes = plt.subplots(len(heights), 1, figsize=(7.0, sum(heights) + 0.6),
                                 gridspec_kw={"height_ratios": heights}, squeeze=False)
        for ax, (label, channel_rows) in zip(axes[:, 0], channels.items()):
            y = np.arange(len(channel_rows))
            lows = np.array([r["low"] for r in channel_rows])
            highs = np.array([r["high"] for r in channel_rows])
            ax.barh(y, highs - lows, left=lows, height=0.6, color="#9ecae1", edgecolor="#3182bd", linewidth=0.5)
            ax.scatter([r["nominal"] for r in channel_rows], y, marker="|", color="black", s=60, zorder=3)
            for yi, r in zip(y, channel_rows):
                if r["identified"] is not None:
                    color = "#2ca02c" if r["covered"] else "#d62728"
                    ax.errorbar(r["identified"], yi, xerr=[[r["identified"] - r["identified_low"]],
                                                          [r["identified_high"] - r["identified"]]],
                                fmt="o", color=color, markersize=3, capsize=2, zorder=4)
            ax.set_yticks(y, [r["element"] for r in channel_rows])
            ax.invert_yaxis()
            first = channel_rows[0]
            ax.set_title(f"{label} [{first['unit']}]  ({first['mode']}, {first['distribution']}, {first['operation']})",
                         loc="left", fontsize=7)
        fig.suptitle(title, fontsize=8)
        fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.25 / (sum(heights) + 0.6)))
        with atomic_path(target) as tmp:
            fig.savefig(tmp, format="svg", metadata={"Date": None, "Creator": None})
        plt.close(fig)


def build_summary(
    dr_json: str | Path,
    params_path: str | Path | None,
    coverage_json: str | Path,
    table_tsv: str | Path,
    figure_svg: str | Path,
    *,
    strict: bool = False,
) -> dict[str, Any]:
    """Coverage check + summary table + figure for one robot (the ``dr_summary`` rule)."""
    from sim2real.files import write_json, write_text

    resolved = load_resolved(dr_json)
    coverage = coverage_summary(resolved, params_path, strict=strict)
    rows = summary_rows(resolved, coverage)
    write_json(coverage_json, coverage)
    write_text(table_tsv, summary_table(rows))
    robot = resolved.get("robot") or "robot"
    plot_summary(rows, f"Domain randomization: {robot} (level ranges at scale 1)", figure_svg)
    return coverage

"""gap.md's runs section: each run's role, the torque it judges, its size and commands (:func:`runs_lines`), then,
collapsed, how the runs were prepared and what their files lacked (empty cells, logging gaps, spikes, held samples)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sim2real.report import details


def runs_lines(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """The runs (role, torque judged, size, commands), then (collapsed) how they were prepared and what their files
    lacked."""
    lines = ["", "## Runs", "", "| run | role | torque judged | samples | duration [s] | commands |",
             "|---|---|---|---|---|---|"]
    for r in runs:
        lines.append(f"| {r['name']} | {r['role']} | `{r['torque_source']}` | {r['samples']} | "
                     f"{r['duration_s']:.2f} | {'yes' if r['has_commands'] else 'no'} |")
    f = runs[0]["filter"]
    preparation = [f"Preparation: {f['resampling']} at {f['resampled_to_hz']:g} Hz "
                   f"(raw steps {f['raw_step_ms']['min']:.2f}-{f['raw_step_ms']['max']:.2f} ms, "
                   f"{f['repeated_samples_dropped']} repeated samples dropped); q filtered by a {f['type']}, "
                   f"order {f['order']}, cutoff {f['cutoff_hz']:g} Hz; velocity: {f['velocity']}; "
                   f"acceleration: {f['acceleration']}; {f['applied_to']}; "
                   f"{f['trimmed_s_each_end']:g} s trimmed at each end"
                   f"{' of each piece' if any('gaps' in r['filter'] for r in runs) else ''}.", ""]
    return lines + [""] + details("How the runs were prepared, and what their files lacked",
                                  preparation + _incomplete_lines(runs) + _gaps_lines(runs) + _spike_lines(runs)
                                   + _held_lines(runs))


def _gaps_lines(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """What the runs' logging gaps did (sim2real.measurements.prepare.prepare_pieces): where each run was split, and
    the pieces left out as too short; nothing when no run has a gap."""
    records = {r["filter"]["gaps"]["run"]: r["filter"]["gaps"] for r in runs if "gaps" in r["filter"]}
    if not records:
        return []
    lines = ["Logging gaps (stamps further apart than the filter can bridge; each piece between them is prepared on "
             "its own, never interpolated across):", ""]
    for run, record in records.items():
        lost = ", ".join(f"{g['lost_s']:.3g} s after {g['after_s']:.2f} s" for g in record["gaps"])
        left = [p for p in record["pieces"] if not p["kept"]]
        text = (f"- {run}: {len(record['gaps'])} gap(s) longer than {record['max_step_s']:.3g} s ({lost}); "
                f"{len(record['pieces']) - len(left)} piece(s) kept")
        if left:
            text += (", left out as too short once the filter's edges are trimmed: "
                     + ", ".join(f"{p['from_s']:.2f}-{p['to_s']:.2f} s" for p in left))
        lines.append(text + ".")
    return [*lines, ""]


def _incomplete_lines(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """The rows each run's file had with an empty cell (sim2real.measurements.runs.read_run: dropped as samples the
    logger lost); nothing when every row was whole."""
    records = {r["filter"]["incomplete_rows"]["run"]: r["filter"]["incomplete_rows"]
               for r in runs if "incomplete_rows" in r["filter"]}
    if not records:
        return []
    lines = ["Rows with an empty cell (blank or NaN), dropped as samples the logger lost (where they make a stretch "
             "longer than the filter can bridge, the run is split there):", ""]
    lines += [f"- {run}: {record['dropped']} of {record['of']} rows ({record['dropped'] / record['of']:.1%}), the first "
              f"{record['first_row']}." for run, record in records.items()]
    return [*lines, ""]


def _spike_lines(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """The lone samples each run had replaced (sim2real.measurements.cleaning.lone_spikes); nothing when none."""
    rows = []
    for r in runs:
        spikes = r["filter"].get("spikes")
        if spikes:
            counts = "; ".join(f"`{kind}` " + ", ".join(f"{joint} {count}" for joint, count in joints.items())
                               for kind, joints in spikes["replaced"].items())
            rows.append(f"- {r['name']}: {counts}.")
    if not rows:
        return []
    scales = next(r["filter"]["spikes"]["scales"] for r in runs if r["filter"].get("spikes"))
    return [f"Spikes (a lone sample of a position or a torque more than {scales:g}x its column's noise from the median "
            "of it and its neighbours: an encoder's or a bus's error, not a motion or a torque), each replaced by that "
            "median:", "", *rows, ""]



def _held_lines(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """The position columns each run's logger held (sim2real.measurements.cleaning.held_columns) and what the
    preparation did about them; nothing when no column was held."""
    rows = [f"- {r['name']}: " + "; ".join(
        f"`{kind}` " + ", ".join(f"{joint} {count} of {r['filter']['held']['of']} rows "
                                 f"({count / r['filter']['held']['of']:.0%})" for joint, count in joints.items())
        for kind, joints in r["filter"]["held"]["held"].items()) + "."
        for r in runs if "held" in r["filter"]]
    if not rows:
        return []
    return ["Held samples (a column repeating the row before while the rest of the row changes: a signal updated "
            "slower than the log). Each such column was taken at its own update instants, its held samples treated "
            "as missing, before it was filtered and differentiated: a hold never reads as the joint stopping.", "",
            *rows, ""]

"""Markdown summary of what changed between two gap reports (base branch vs pull request).

Reads only the stable keys of ``gap.json`` (``robot``, ``ladder[].effects``,
``ladder[].metrics.torque_rmse``, ``noise_floor``, ``diagnosis.candidates``, and the same of the
``actuator`` link where the runs have one), so reviewers see per rung and per joint whether the model
got closer to the measurements or further away.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sim2real.errors import InputError
from sim2real.report import rung_label

GapReport = Mapping[str, Any]


def load_gap(path: str | Path) -> GapReport:
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise InputError(path, None, "file does not exist", "pass the path of a built gap.json") from exc
    except json.JSONDecodeError as exc:
        raise InputError(path, f"line {exc.lineno}", f"is not valid JSON ({exc.msg})", "rebuild it with snakemake") from exc
    if not isinstance(data, dict) or "robot" not in data:
        raise InputError(path, "top level", "has no 'robot' key, so it is not a gap report", "pass results/<robot>/gap.json")
    return data


def _fmt(value: float | None, unit: str = "") -> str:
    return "–" if value is None else f"{value:.4g}{unit}"


def _delta(base: float | None, head: float | None) -> str:
    if base is None or head is None:
        return "new" if base is None and head is not None else "–"
    diff = head - base
    pct = f" ({100.0 * diff / base:+.1f}%)" if base else ""
    arrow = "🟢" if diff < 0 else ("🔴" if diff > 0 else "⚪")
    return f"{arrow} {diff:+.4g}{pct}"


def _label(rung: Mapping[str, Any] | None) -> str:
    return rung_label((rung or {}).get("effects") or [], whole=True)


def _torque_rmse(rung: Mapping[str, Any] | None) -> Mapping[str, Any]:
    if not rung:
        return {}
    return rung.get("metrics", {}).get("torque_rmse", {}) or {}


def _top_candidate(report: GapReport | None) -> str:
    if not report:
        return "–"
    diagnosis = report.get("diagnosis") or {}
    candidates: Sequence[Mapping[str, Any]] = diagnosis.get("candidates") or []
    if not candidates:
        return diagnosis.get("verdict") or "no candidate"
    top = candidates[0]
    joints = ", ".join(top.get("joints") or [])
    return f"`{top.get('effect')}` on {joints or 'all joints'} (explains {100 * float(top.get('explained', 0)):.0f}%)"


def gap_diff_markdown(base: GapReport | None, head: GapReport) -> str:
    """Markdown table of head vs base: ladder rungs, last rung per joint, top diagnosis."""
    robot = head.get("robot", "?")
    lines = [f"### Reality gap: `{robot}`", ""]
    if base is None:
        lines += ["No gap report on the base branch to compare with; showing this branch only.", ""]
    head_ladder = list(head.get("ladder") or [])
    base_ladder = list((base or {}).get("ladder") or [])
    if head_ladder:
        lines += _rung_rows(head_ladder, base_ladder) + [""]
        # The model each branch ends with: its last rung, whatever effects either added.
        last = head_ladder[-1]
        base_last = base_ladder[-1] if base_ladder else None
        head_joints = _torque_rmse(last).get("per_joint", {})
        base_joints = _torque_rmse(base_last).get("per_joint", {})
        floor = (head.get("noise_floor") or {}).get("torque_rmse", {}).get("per_joint", {})
        models = (f"base {_label(base_last)}, this branch {_label(last)}" if base_last is not None
                  and _label(base_last) != _label(last) else _label(last))
        lines += [
            f"Per joint, the last rung of each branch, the model it calibrates ({models}):",
            "",
            "| joint | base | this branch | change | noise floor |",
            "|---|---|---|---|---|",
        ]
        for joint in head_joints:
            b, h = base_joints.get(joint), head_joints.get(joint)
            lines.append(f"| {joint} | {_fmt(b)} | {_fmt(h)} | {_delta(b, h)} | {_fmt(floor.get(joint))} |")
        lines.append("")
    else:
        lines += ["This gap report has no model ladder.", ""]
    lines += [
        f"**Top diagnosis** — base: {_top_candidate(base)}; this branch: {_top_candidate(head)}",
        "",
    ]
    if head.get("actuator"):
        base_link = (base or {}).get("actuator")
        lines += ["Actuator link (measured against commanded torque):", ""]
        lines += _rung_rows(head["actuator"].get("ladder") or [], (base_link or {}).get("ladder") or []) + [""]
        lines += [f"**Top diagnosis, actuator link** — base: {_top_candidate(base_link)}; this branch: "
                  f"{_top_candidate(head['actuator'])}", ""]
    return "\n".join(lines)


def _rung_rows(head_ladder: Sequence[Mapping[str, Any]], base_ladder: Sequence[Mapping[str, Any]]) -> list[str]:
    """One row per rung of this branch against the base's rung with the same effects; removed rungs last."""
    base_by_label = {_label(r): r for r in base_ladder}
    lines = ["| rung | holdout torque RMSE (base) | (this branch) | change |", "|---|---|---|---|"]
    for rung in head_ladder:
        label = _label(rung)
        b = _torque_rmse(base_by_label.get(label)).get("overall")
        h = _torque_rmse(rung).get("overall")
        lines.append(f"| {label} | {_fmt(b, ' N·m')} | {_fmt(h, ' N·m')} | {_delta(b, h)} |")
    for label in base_by_label:
        if label not in {_label(r) for r in head_ladder}:
            lines.append(f"| {label} | {_fmt(_torque_rmse(base_by_label[label]).get('overall'), ' N·m')} | removed | – |")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="sim2real gap-diff", description=__doc__)
    parser.add_argument("base", help="gap.json of the base branch (may be missing: then only the head is shown)")
    parser.add_argument("head", help="gap.json of this branch")
    args = parser.parse_args(argv)
    base = load_gap(args.base) if Path(args.base).exists() else None
    print(gap_diff_markdown(base, load_gap(args.head)))
    return 0

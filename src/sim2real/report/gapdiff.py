"""Markdown summary of what changed between two gap reports (base branch vs pull request): the pull-request comment.

It says each side's verdict and what changed in it, then what a reviewer must look at (a rung worse beyond the
noise, a verdict that changed, a body newly held at a bound, a new implausible body), then the ladder and the model
each side ends with, joint by joint. A change is marked 🔴/🟢 only where the noise can resolve it
(:func:`resolution`): smaller, it is shown unchanged (⚪), and two fits that differ only within the noise read "no
change beyond the noise".

Reads gap.json through :class:`~sim2real.report.gap_document.GapReport`, and of it only the stable parts (the robot,
the holdout runs' lengths, each rung's effects and holdout torque RMSE, the last rung's link inertias, the noise
floor, the diagnosis, and the same of the actuator link where the runs have one).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.errors import InputError
from sim2real.identification.ladder_rows import Rung
from sim2real.report import rung_label
from sim2real.report.gap_document import GapReport
from sim2real.report.verdicts import BOUND_TEXT


@dataclass(frozen=True)
class _Link:
    """One link of a report as the comment compares it: the report's runs, the link's noise floor (its torque RMSE),
    rungs and diagnosis."""

    runs: tuple[Mapping[str, Any], ...]
    floor: Mapping[str, Any]
    ladder: tuple[Rung, ...]
    diagnosis: Mapping[str, Any] | None


def _link(report: GapReport, actuator: bool) -> _Link:
    """The body link of ``report``, or its actuator link (``actuator``; nothing of it where it has none). A link is
    judged on its report's runs."""
    runs = report.runs or ()
    if not actuator:
        return _Link(runs, report.floor, report.ladder or (), report.diagnosis)
    if report.actuator is None:
        return _Link(runs, {}, (), None)
    return _Link(runs, report.actuator.floor, report.actuator.ladder, report.actuator.diagnosis)


# What no change of code can promise to hold: a held-out metric moves this much across CPUs and BLAS kernels with the
# same code and data (tests/test_loop_pinned.py, docs/performance.md): 1 % of itself or 2.5 % of its joint's floor.
REPRODUCIBLE_RELATIVE = 0.01
REPRODUCIBLE_FLOOR_SHARE = 0.025
# A change is resolved beyond this many standard errors of the joint's holdout RMSE (:func:`resolution`).
RESOLVING_ERRORS = 2.0

UNCHANGED, WORSE, BETTER = "⚪", "🔴", "🟢"
NO_CHANGE = "No change beyond the noise."
STATUS_TEXT = {"add_effect": "an effect to add", "not_told_apart": "effects not told apart",
               "at_noise_floor": "at the noise floor", "unexplained": "unexplained: the library lacks what is left"}


def load_gap(path: str | Path) -> GapReport:
    """gap.json as a :class:`GapReport`; a missing file, or one that is no gap report, is an input error."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise InputError(path, None, "file does not exist", "pass the path of a built gap.json") from exc
    except json.JSONDecodeError as exc:
        raise InputError(path, f"line {exc.lineno}", f"is not valid JSON ({exc.msg})", "rebuild it with snakemake") from exc
    if not isinstance(data, dict) or "robot" not in data:
        raise InputError(path, "top level", "has no 'robot' key, so it is not a gap report", "pass results/<robot>/gap.json")
    return GapReport.from_document(data)


# --- what the noise can resolve -----------------------------------------------------------------------------------

def independent_samples(report: GapReport | _Link | Mapping[str, Any] | None) -> float | None:
    """Roughly independent samples of the holdout runs: their length times twice the filter's cutoff (samples closer
    than half a period of the cutoff move together); None where the report does not say."""
    if report is not None and not isinstance(report, _Link):
        report = _link(GapReport.of(report), actuator=False)
    runs = [r for r in (report.runs if report is not None else ()) if r.get("role") == "holdout"]
    try:
        count = sum(float(r["duration_s"]) * 2.0 * float(r["filter"]["cutoff_hz"]) for r in runs)
    except (KeyError, TypeError, ValueError):
        return None
    return count if count > 0 else None


def resolution(value: float, floor: float | None, samples: float | None) -> float:
    """The smallest change of a joint's holdout RMSE ``value`` the noise can resolve: what a metric moves across
    machines (:data:`REPRODUCIBLE_RELATIVE`, :data:`REPRODUCIBLE_FLOOR_SHARE` of the floor), and
    :data:`RESOLVING_ERRORS` standard errors of the RMSE that white noise of the joint's floor ``floor`` leaves on
    ``samples`` independent samples: the mean square's variance (2 s^4 + 4 s^2 e^2) / n for a model error e above
    noise s, carried to the RMSE through its derivative 1 / (2 RMSE)."""
    tolerance = REPRODUCIBLE_RELATIVE * abs(value)
    if floor is None or floor <= 0:
        return tolerance
    tolerance = max(tolerance, REPRODUCIBLE_FLOOR_SHARE * floor)
    if samples and value > 0:
        excess = max(value**2 - floor**2, 0.0)
        standard_error = math.sqrt((2 * floor**4 + 4 * floor**2 * excess) / samples) / (2 * value)
        tolerance = max(tolerance, RESOLVING_ERRORS * standard_error)
    return tolerance


@dataclass(frozen=True)
class Change:
    """One number of both sides: its mark (⚪ within the noise, 🔴 worse, 🟢 better) and its words."""

    mark: str
    text: str


def change(base: float | None, head: float | None, resolved: float) -> Change:
    """``head`` against ``base``, a change within ``resolved`` shown unchanged."""
    if base is None or head is None:
        return Change(UNCHANGED, "new" if base is None and head is not None else "–")
    diff = head - base
    pct = f" ({100.0 * diff / base:+.1f}%)" if base else ""
    if abs(diff) <= resolved:
        return Change(UNCHANGED, f"{UNCHANGED} within the noise ({diff:+.2g})")
    mark = WORSE if diff > 0 else BETTER
    return Change(mark, f"{mark} {diff:+.4g}{pct}")


def _fmt(value: float | None, unit: str = "") -> str:
    return "–" if value is None else f"{value:.4g}{unit}"


def _label(rung: Rung | None) -> str:
    return rung_label(rung.effects if rung is not None else (), whole=True)


def _torque_rmse(rung: Rung | None) -> Mapping[str, Any]:
    return rung.metrics.torque_rmse if rung is not None else {}


def _floors(link: _Link | None) -> Mapping[str, float]:
    return link.floor.get("per_joint", {}) if link is not None else {}


def joint_changes(base_rung: Rung | None, head_rung: Rung, base: _Link | None,
                  head: _Link) -> dict[str, tuple[float | None, float | None, Change]]:
    """Each joint of ``head_rung``: (base, head, change), the change resolved against the larger floor and the
    shorter holdout of the two sides."""
    base_joints, head_joints = _torque_rmse(base_rung).get("per_joint", {}), _torque_rmse(head_rung).get("per_joint", {})
    floors = [_floors(base), _floors(head)]
    counts = [n for n in (independent_samples(base), independent_samples(head)) if n]
    samples = min(counts) if counts else None
    out = {}
    for joint, h in head_joints.items():
        b = base_joints.get(joint)
        floor = max((f[joint] for f in floors if f.get(joint) is not None), default=None)
        resolved = resolution(max(v for v in (b, h) if v is not None), floor, samples)
        out[joint] = (b, h, change(b, h, resolved))
    return out


# --- each side's verdict, and what a reviewer must look at ------------------------------------------------------------

def _headline(diagnosis: Mapping[str, Any] | None) -> str:
    """A verdict's first sentence (its status's headline), or its status in words."""
    if not diagnosis:
        return "no diagnosis"
    text = str(diagnosis.get("verdict") or "")
    first = text.split(". ", 1)[0].rstrip(".")
    return (first + ".") if first else STATUS_TEXT.get(str(diagnosis.get("status")), "no verdict")


def _named(diagnosis: Mapping[str, Any] | None) -> tuple[str | None, str | None]:
    """(status, the line it recommends) of a diagnosis."""
    if not diagnosis:
        return None, None
    status = diagnosis.get("status")
    candidates = diagnosis.get("candidates") or []
    line = candidates[0].get("add") if status == "add_effect" and candidates else None
    return status, line


def verdict_lines(base: Mapping[str, Any] | None, head: Mapping[str, Any] | None, link: str) -> tuple[list[str], bool]:
    """Each side's verdict and what changed in it; whether it changed (its status or the line it recommends)."""
    b_status, b_line = _named(base)
    h_status, h_line = _named(head)
    changed = base is not None and (b_status, b_line) != (h_status, h_line)
    lines = [f"**Verdict{link}** — this branch: {_headline(head)}"]
    if base is None:
        return lines, False
    if not changed:
        return [*lines, "", "Base: the same verdict."], False
    what = (f"the status went from {STATUS_TEXT.get(str(b_status), b_status)} to "
            f"{STATUS_TEXT.get(str(h_status), h_status)}" if b_status != h_status else
            f"the line to add went from `{b_line}` to `{h_line}`")
    return [*lines, "", f"Base: {_headline(base)}", "", f"What changed: {what}."], True


def _bodies(report: GapReport | None, key: str) -> dict[str, list[str]]:
    """Bodies of the last rung's link inertias with a ``key`` ("binding": held at a bound, "implausible") set."""
    ladder = (report.ladder or ()) if report is not None else ()
    link = (ladder[-1].values.get("link_inertia") or {}) if ladder else {}
    return {name: list(b.get(key) or []) for name, b in (link.get("bodies") or {}).items() if b.get(key)}


def bodies_lines(base: GapReport | None, head: GapReport) -> list[str]:
    """Bodies newly held at a bound, and newly implausible, in the model this branch ends with."""
    lines = []
    held, held_before = _bodies(head, "binding"), _bodies(base, "binding")
    for name, bounds in held.items():
        new = [b for b in bounds if b not in held_before.get(name, [])]
        if new:
            lines.append(f"- **{name}** newly held at a bound: {', '.join(BOUND_TEXT.get(b, b) for b in new)}.")
    implausible, before = _bodies(head, "implausible"), _bodies(base, "implausible")
    for name, reasons in implausible.items():
        new = [r for r in reasons if r not in before.get(name, [])]
        if new:
            lines.append(f"- **{name}** newly implausible: {'; '.join(new)}.")
    return lines


# --- the comment ------------------------------------------------------------------------------------------------------

def _rung_rows(head_link: _Link, base_link: _Link | None) -> tuple[list[str], list[str]]:
    """One row per rung of this branch against the base's rung with the same effects, removed rungs last; and the
    rungs worse beyond the noise (a joint of theirs worse beyond its resolution)."""
    head_ladder, base_ladder = head_link.ladder, base_link.ladder if base_link is not None else ()
    base_by_label = {_label(r): r for r in base_ladder}
    lines = ["| rung | holdout torque RMSE (base) | (this branch) | change |", "|---|---|---|---|"]
    worse = []
    for rung in head_ladder:
        label = _label(rung)
        before = base_by_label.get(label)
        b, h = _torque_rmse(before).get("overall"), _torque_rmse(rung).get("overall")
        marks = {c.mark for *_, c in joint_changes(before, rung, base_link, head_link).values()} if before else set()
        mark = WORSE if WORSE in marks else BETTER if BETTER in marks else UNCHANGED
        text = "new" if before is None else (f"{UNCHANGED} within the noise" if mark == UNCHANGED else
                                             f"{mark} {h - b:+.4g} ({100.0 * (h - b) / b:+.1f}%)" if b else mark)
        if mark == WORSE:
            worse.append(label)
        lines.append(f"| {label} | {_fmt(b, ' N·m')} | {_fmt(h, ' N·m')} | {text} |")
    for label in base_by_label:
        if label not in {_label(r) for r in head_ladder}:
            lines.append(f"| {label} | {_fmt(_torque_rmse(base_by_label[label]).get('overall'), ' N·m')} | removed | – |")
    return lines, worse


def _joint_table(base: _Link | None, head: _Link) -> tuple[list[str], bool]:
    """Per joint, the last rung of each branch; whether any joint changed beyond the noise."""
    last, base_last = head.ladder[-1], ([None, *(base.ladder if base is not None else ())])[-1]
    models = (f"base {_label(base_last)}, this branch {_label(last)}" if base_last is not None
              and _label(base_last) != _label(last) else _label(last))
    floor = _floors(head)
    lines = [f"Per joint, the last rung of each branch, the model it calibrates ({models}); a change the noise floor "
             "and the holdout's length cannot resolve is marked ⚪:", "",
             "| joint | base | this branch | change | noise floor |", "|---|---|---|---|---|"]
    changes = joint_changes(base_last, last, base, head)
    for joint, (b, h, c) in changes.items():
        lines.append(f"| {joint} | {_fmt(b)} | {_fmt(h)} | {c.text} | {_fmt(floor.get(joint))} |")
    return lines, any(c.mark != UNCHANGED for *_, c in changes.values())


@dataclass(frozen=True)
class LinkDiff:
    """One link's part of the comment: its verdict, what a reviewer must look at, its tables, whether anything of
    it changed beyond the noise."""

    verdict: list[str]
    look: list[str]
    tables: list[str]
    changed: bool


def link_diff(base: GapReport | None, head: GapReport, actuator: bool) -> LinkDiff:
    """The body link or the actuator link (``actuator``): its verdict, its rungs worse beyond the noise, its ladder
    and (the body link) its joints."""
    link = " (actuator link)" if actuator else ""
    head_link = _link(head, actuator)
    base_link = _link(base, actuator) if base is not None else None
    head_diagnosis, base_diagnosis = head_link.diagnosis, base_link.diagnosis if base_link is not None else None
    verdict, verdict_changed = verdict_lines(base_diagnosis if base_link is not None else None, head_diagnosis, link)
    rows, worse = _rung_rows(head_link, base_link)
    tables = ([f"Ladder{link}:", ""] if actuator else []) + rows + [""]
    changed = verdict_changed or any(WORSE in r or BETTER in r for r in rows)
    look = [f"- {WORSE} rung `{label}`{link} is worse beyond the noise. Base verdict: {_headline(base_diagnosis)} "
            f"This branch: {_headline(head_diagnosis)}" for label in worse] if base is not None else []
    look += [f"- The verdict{link} changed (above)."] if verdict_changed else []
    if not actuator:
        table, joints_changed = _joint_table(base_link, head_link)
        tables += table + [""]
        changed = changed or joints_changed
    return LinkDiff(verdict + [""], look, tables, changed)


def gap_diff_markdown(base: GapReport | Mapping[str, Any] | None, head: GapReport | Mapping[str, Any]) -> str:
    """The pull-request comment of one robot: each side's verdict and what changed, what to look at, the ladder and
    the joints of the model each side ends with."""
    head = GapReport.of(head)
    base = GapReport.of(base) if base is not None else None
    lines = [f"### Reality gap: `{head.robot}`", ""]
    if base is None:
        lines += ["No gap report on the base branch to compare with; showing this branch only.", ""]
    if not head.ladder:
        return "\n".join(lines + ["This gap report has no model ladder.", ""])
    links = [link_diff(base, head, False)] + ([link_diff(base, head, True)] if head.actuator is not None else [])
    for part in links:
        lines += part.verdict
    if base is not None:
        look = [line for part in links for line in part.look] + bodies_lines(base, head)
        if look:
            lines += ["**Look at:**", "", *look, ""]
        elif not any(part.changed for part in links):
            lines += [f"**{NO_CHANGE}**", ""]
    return "\n".join(lines + [line for part in links for line in part.tables])


def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="sim2real gap-diff", description=__doc__)
    parser.add_argument("base", help="gap.json of the base branch (may be missing: then only the head is shown)")
    parser.add_argument("head", help="gap.json of this branch")
    args = parser.parse_args(argv)
    base = load_gap(args.base) if Path(args.base).exists() else None
    print(gap_diff_markdown(base, load_gap(args.head)))
    return 0
